"""Keeping the parameters to a target bitrate, closed loop: the quality level from a sample of the
call itself, then the encoder's dead zone as the call goes.

How many bits a level costs depends on the speaker, the layout and the
tracker's jitter far more than on the level alone (a factor of two between the
dev clips), so a table of typical rates misses. The sender holds its first
second anyway to find the rest face; coding that second at every level takes a
millisecond, and the finest level that fits is the choice.

The level goes in the header; a speaker livelier after the first second costs more
(tpsmm_driving: 1.57 kbit/s over the clip at the level that coded its first second within 1.5).
The dead zone is the encoder's alone (the receiver neither knows nor needs it), so
:class:`RateKeeper` widens it while the last two seconds cost more than the rate; where the keeper
is given the level, it also moves it, a keyframe naming the header at another level
(``Header.levels``): coarser once the last second's pace would fill two seconds past the rate,
finer again once two seconds have cost well under it; at the coarsest level it says it is short
(over datagrams the sender then sends a copy of each packet fewer).
"""

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from facedeform.protocol.encoder import Datagrams, PacketEncoder, stream_size
from facedeform.protocol.header import Header
from facedeform.protocol.quantise import QUALITIES
from facedeform.protocol.secure import envelope_bytes


def sample_bits_per_second(header: Header, sample: Sequence[tuple[np.ndarray, bool]], frames_per_packet: int,
                           dead_zone: float, seal_bytes: int = 0, copies: int | None = None, key_every: int = 1,
                           rounded: Sequence[str] = ()) -> float:
    """Bit/s of ``sample`` ((k,) params, face seen) coded as a byte stream of its own under ``header``
    (without its face model or end mark: what every second of the call costs). ``seal_bytes``: what
    sealing adds to each packet (``SecureSealer.overhead``, and the envelope's length field; a sealed
    packet also takes a sync byte). ``copies``: the packets go as datagrams, each carrying that many
    packets before it again (``Datagrams``; the header's repeats for late joiners not counted).
    ``key_every``: a keyframe at every so many of the header's key places (``PacketEncoder.key_every``);
    ``rounded``: as ``PacketEncoder``'s."""
    encoder = PacketEncoder(replace(header, model_size=0, preview_size=0), frames_per_packet, dead_zone=dead_zone,
                            rounded=rounded)
    encoder.key_every = key_every
    packets = [p for params, seen in sample for p in encoder.frame(params, seen)] + encoder.end()[:-1]
    if copies is None:
        size = stream_size(packets, sealed=bool(seal_bytes))
    else:
        packets = Datagrams(b"", copies, header_every=0, eager=0).add(packets)
        size = sum(map(len, packets))
    if seal_bytes:
        size += sum(envelope_bytes(len(p), seal_bytes) for p in packets)
    return 8 * size * header.fps / len(sample)


def quality_for_bitrate(header_at: Callable[[int], Header], sample: Sequence[tuple[np.ndarray, bool]],
                        bits_per_second: float, frames_per_packet: int, dead_zone: float, seal_bytes: int = 0,
                        copies: int | None = None, finest: int = max(QUALITIES), rounded: Sequence[str] = ()) -> int:
    """The finest level up to ``finest`` whose ``header_at(level)`` codes ``sample`` within
    ``bits_per_second``; the coarsest level if none does. ``copies``, ``rounded``: as
    :func:`sample_bits_per_second`'s."""
    for quality in sorted((q for q in QUALITIES if q <= finest), reverse=True):
        if sample_bits_per_second(header_at(quality), sample, frames_per_packet, dead_zone,
                                  seal_bytes, copies, rounded=rounded) <= bits_per_second:
            return quality
    return min(QUALITIES)


#: The dead zone's widest under a rate, in steps: at 3 steps tpsmm_driving's level-3 stream costs
#: 22 % less (1.57 to 1.23 kbit/s) for 0.02 dB of whole-picture PSNR; past it a coarser level is the
#: cheaper error, and that needs a new header.
WIDEST = 3.0
WINDOW = 2.0  # seconds over which the rate is kept
MOVE = 0.1  # steps the zone moves a frame: from its narrowest to WIDEST in a second at 25 frames/s
SLACK = 0.9  # the zone narrows again only once the window costs less than this share of the rate
#: The level goes one finer only once a whole window at the narrowest zone has cost less than this share of
#: the rate: a level costs about 1.4 times the one below it (the bundled clip: 0.71, 1.08 and 1.49 kbit/s at
#: levels 2, 3 and 4), so the finer one then keeps within SLACK of it, and a level is not left and taken
#: back every few seconds.
FINER = 0.6
#: The level goes one coarser once the last second's pace, kept for a whole window, would cost more than
#: this share of the rate: what the widest dead zone takes back is left to it.
COARSER = 1.0


class RateKeeper:
    """The encoder's dead zone for each next frame, so that the parameters' bits over any
    WINDOW seconds stay within ``bits_per_second``: wider while the window costs more, back
    towards ``narrowest`` (the call's own dead zone) once it costs less than SLACK of it. The
    call's first frames are held to a whole window's budget too, not to their own few frames' (which
    the first keyframe alone overspent, widening the dead zone of a call far below its rate)."""

    def __init__(self, bits_per_second: float, fps: float, narrowest: float, level: int | None = None,
                 finest: int = max(QUALITIES)) -> None:
        window = max(1, round(WINDOW * fps))
        self._allowed = window * bits_per_second / fps  # bits a window
        self._recent: deque[int] = deque(maxlen=window)
        self._passing: deque[int] = deque(maxlen=window)  # bits of the same frames the caller sends once only
        self._narrowest = self.dead_zone = narrowest
        #: the quantiser level for the next frame, where the keeper moves it (None: the header's, fixed)
        self.level = level
        self._finest = finest
        self._second = max(1, round(fps))  # frames the pace is taken over: from a keyframe to the next
        self._since = 0  # frames at this level
        #: the last step found the pace over the rate at the coarsest level (once a second while it is):
        #: what else the caller can shed (over datagrams, a copy of each packet) is its to shed
        self.short = False

    def step(self, bits: int, passing: int = 0) -> float:
        """The dead zone for the next frame, after one that cost ``bits`` (0 while its packet waits); a
        new :attr:`level` where the keeper moves it. ``passing``: bits beside them of what goes only for a
        while (over datagrams, the eager repeats of the header at the call's start), which a finer level
        must also leave room for but which a coarser one would not save."""
        self._recent.append(bits)
        self._passing.append(passing)
        spent, allowed = sum(self._recent), self._allowed
        if spent > allowed:
            self.dead_zone = min(max(WIDEST, self._narrowest), self.dead_zone + MOVE)
        elif spent < SLACK * allowed:
            self.dead_zone = max(self._narrowest, self.dead_zone - MOVE)
        self.short = False
        if self.level is not None:
            self._since += 1
            self._move_level(spent)
        return self.dead_zone

    def _move_level(self, spent: int) -> None:
        """Coarser once the last second at this level, its pace kept for a whole window, costs more than the
        rate; finer once a whole window at this level and the narrowest zone has cost under FINER of it."""
        assert self.level is not None
        window, second = self._recent.maxlen or 1, self._second
        if self._since >= second:
            pace = sum(list(self._recent)[-second:]) / second
            if pace * window > COARSER * self._allowed:
                if self.level > min(QUALITIES):
                    self.level -= 1
                else:
                    self.short = True
                self._since = 0
                return
        if (self._since >= window and self.level < self._finest and self.dead_zone == self._narrowest
                and spent + sum(self._passing) < FINER * self._allowed):
            self.level, self._since = self.level + 1, 0
