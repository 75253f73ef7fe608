"""What fd-send can be asked for, with its defaults and limits in one place.

:class:`SendConfig` configures a :class:`sender.session.SendSession`; the
command line reads its defaults and :data:`LIMITS` from here instead of
writing them again, and a value out of range is one :class:`InputError` line
whether it came from the command line or from code.
"""

from dataclasses import dataclass, fields

from facedeform.codec.model.regions import DEFAULT_RULE, check_rule
from facedeform.common.cli import describe_range, in_range
from facedeform.common.errors import InputError
from facedeform.protocol.encoder import COPIES, MAX_DEAD_ZONE
from facedeform.protocol.framing import MAX_COUNT, MAX_REDUNDANCY
from facedeform.protocol.header import MAX_DIVISOR
from facedeform.protocol.quantise import DEAD_ZONE, QUALITIES
from facedeform.protocol.secure import DEFAULT_TAG_BITS, TAG_BITS
from facedeform.sender.analysis import LAYOUT_NAMES

BITRATE = (1.0, 1e6)  # bit/s
#: Frames a packet holds by default on a byte stream, and over datagrams, where a datagram of one frame
#: makes a burst of lost datagrams cost half the frames: with three copies and a keyframe every 6 frames,
#: no frame was concealed longer than 10 frames in bursts of 8 datagrams on four dev clips' streams
#: (18 at 2 frames and a keyframe every 10), for 22 % more bits (docs/bitstream.md, "Bursts").
STREAM_FRAMES, DATAGRAM_FRAMES = 2, 1
#: bit/s the parameters keep within by default with the speaker's own motion basis (fd-enroll): at
#: level 3 it cost 0.94-2.47 kbit/s on the dev clips, the liveliest talkers the most; kept within
#: this, the picture moved by at most 0.07 dB (README, expression table).
SPEAKER_RATE = 1500.0
#: Where the parameters keep all of a --bitrate (or SPEAKER_RATE by default), their level must code
#: the first second within this share of it: the rate keeper's dead zone could not bring back a level
#: finer than the rest of a call affords before a short call ended (lipnet's 3-second clip at 1.5
#: kbit/s took level 4 from its first second, and its first 2 s cost 1.165 times the rate).
LEVEL_SHARE = 0.9
#: name -> (lowest, highest) accepted value of the numeric settings (inclusive; None: unbounded).
#: --quality N: the whole call's rate in bit/s, as --bitrate gives it. 1 is the face model alone (the
#: picture layer pays from about 3 kbit/s at 256x256); each step up buys picture (docs/picture_layer.md).
QUALITY_RATES = {1: 1500.0, 2: 4000.0, 3: 10000.0, 4: 20000.0, 5: 30000.0}
LIMITS: dict[str, tuple[float, float | None]] = {
    "level": (min(QUALITIES), max(QUALITIES)),
    "quality": (min(QUALITY_RATES), max(QUALITY_RATES)),
    "frames_per_packet": (1, MAX_COUNT),
    "smoothing": (0.0, 10.0),
    "dead_zone": (0.5, MAX_DEAD_ZONE),
    "bitrate": BITRATE,
    "divisor": (1, MAX_DIVISOR),
    "neutral": (0, None),
    "redundancy": (0, MAX_REDUNDANCY),
    "ahead": (0.0, 1.0),
}
#: Seconds a receiver may hold a frame for the picture layer's next video frame (--ahead): at 4 kbit/s
#: the layer's video frames come every 4-15 frames, at 10 every 2-6; held, the frames between are drawn
#: from both (codec/render/frame_video.VideoLayer.draw). At 4 kbit/s on three dev crops (KatieHill, d12,
#: tpsmm_driving) 0.3 s lost 0.01-0.02 dB against 0.5, and 1 s gained 0.01 on the first two.
AHEAD = 0.5


@dataclass(frozen=True)
class SendConfig:
    """How a call is coded.

    level: quantiser level (``protocol.quantise``; None: its DEFAULT_QUALITY, and with the speaker's
    own motion basis the finest that keeps the first second within :data:`SPEAKER_RATE`'s share); quality: 1-5, the
    ``bitrate`` of :data:`QUALITY_RATES` (one of level, quality and bitrate); frames_per_packet: frames
    sent together (fewer framing bits, more latency; None: :data:`STREAM_FRAMES`, over datagrams
    :data:`DATAGRAM_FRAMES`); layout: one of ``sender.analysis.LAYOUT_NAMES``;
    neutral: the rest frame's index (None: chosen in the first second); smoothing: One Euro
    strength (0: off); embed_face: a personal face model given to the session (fd-enroll) is
    carried in the stream (else only its id, the receiver holding it); key: a pre-shared key
    (``common.keys``) to seal every packet with, tags of ``tag_bits``; dead_zone: the encoder's
    dead zone in quantiser steps (0.5: plain rounding); bitrate: bit/s to aim at instead of a
    ``level`` (the finest level that codes the call's first second within it, chosen before the
    header goes out, and a dead zone widened as the call goes where it costs more; where the
    parameters keep the whole rate, the level moved mid-call too: ``protocol.rate``);
    basis: code the principal components of the first second's motion
    (``protocol.basis``) instead of each parameter; divisor: send one frame in this many, the
    receiver interpolates the others; datagrams: the packets go one per UDP datagram, made ready
    for loss and late join by ``protocol.encoder.Datagrams``, each frames datagram carrying the
    ``redundancy`` frames packets before it again; rule: the deformation rule
    (``codec.model.regions.RULES``) the parameters are fitted to and the receiver deforms with, named in
    the header; picture_layer: with a ``bitrate`` and a face with a reference picture, spend what
    the parameters leave of it on the real frame as a small video where the model's picture
    misses it (sender/picture_layer.py; the parameters then aim at :func:`parameter_rate` of it);
    paced_face: the face model carried in the stream goes beside the frames within ``bitrate``, a
    preview first, instead of before the first frame (sender/face_pacing.py; over datagrams round and
    round until the receiver reports it held); ahead: seconds (at most header.MAX_AHEAD frames) the
    receiver holds a frame between two of the picture layer's video frames for the next one, to draw
    it from both (0: from the last alone, at once).
    """

    level: int | None = None
    frames_per_packet: int | None = None
    layout: str = "auto"
    neutral: int | None = None
    smoothing: float = 1.0
    embed_face: bool = True
    key: bytes | None = None
    tag_bits: int = DEFAULT_TAG_BITS
    dead_zone: float = DEAD_ZONE
    bitrate: float | None = None
    basis: bool = True
    divisor: int = 1
    datagrams: bool = False
    redundancy: int = COPIES
    rule: str = DEFAULT_RULE
    picture_layer: bool = True
    quality: int | None = None
    paced_face: bool = False
    ahead: float = AHEAD

    def __post_init__(self) -> None:
        for name, (lo, hi) in LIMITS.items():
            value = getattr(self, name)
            if value is not None and not in_range(value, lo, hi):
                raise InputError(f"{name.replace('_', ' ')} must be {describe_range(lo, hi)}, not {value!r}")
        if sum(v is not None for v in (self.level, self.quality, self.bitrate)) > 1:
            raise InputError("give one of a quality, a bitrate and a level, not more")
        if self.quality is not None:
            object.__setattr__(self, "bitrate", QUALITY_RATES[self.quality])
        if self.layout not in LAYOUT_NAMES:
            raise InputError(f"unknown layout {self.layout!r} (one of {', '.join(LAYOUT_NAMES)})")
        check_rule(self.rule)
        if self.paced_face and self.bitrate is None:
            raise InputError("a paced face goes within a --bitrate (or --quality): give one")
        if self.paced_face and not self.embed_face:
            raise InputError("a paced face goes in the stream: not with --face-by-id")
        if self.tag_bits not in TAG_BITS:
            raise InputError(f"tag bits must be a multiple of 8 from {TAG_BITS[0]} to {TAG_BITS[-1]}")

    @property
    def packet_frames(self) -> int:
        """Frames a packet holds: ``frames_per_packet`` or its default for the transport."""
        return self.frames_per_packet or (DATAGRAM_FRAMES if self.datagrams else STREAM_FRAMES)


#: With the picture layer, the parameters aim at this share of the rate, and at least PARAMETER_FLOOR bit/s,
#: but at most PARAMETER_CAP of it: their level is chosen once, from the call's first second, and livelier
#: talking later costs more (on the dev clips up to 26 % over a 2-second window when they aimed at all of it).
#: A floor of 1.2 kbit/s instead of 1.6, once the model carried the video between its frames, gave the nine
#: dev clips +0.11 dB at 4 kbit/s (-0.11 to +0.53) and +0.23 dB on the 5th percentile (docs/picture_layer.md).
PARAMETER_SHARE, PARAMETER_FLOOR, PARAMETER_CAP = 0.2, 1200.0, 0.75


def parameter_rate(bitrate: float) -> float:
    """bit/s the parameters aim at when the picture layer shares ``bitrate`` with them."""
    return min(PARAMETER_CAP * bitrate, max(PARAMETER_FLOOR, PARAMETER_SHARE * bitrate))


def default(name: str):
    """The default of one setting, for the command line's help and defaults."""
    return next(f.default for f in fields(SendConfig) if f.name == name)
