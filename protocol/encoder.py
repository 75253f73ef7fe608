"""Parameters in, packets out: quantise, predict in closed loop, code, frame.

:class:`PacketEncoder` returns packets for datagram transports;
:class:`StreamEncoder` returns the same packets framed for byte streams (:func:`frame_bytes`).
The encoder records what the decoder will output for each coded frame
(:attr:`PacketEncoder.reconstruction`): with a dead zone that is not the nearest
quantised value, so it is the only exact prediction of the receiver.
"""

from collections.abc import Iterable, Sequence

import numpy as np

from facedeform.common.errors import BitstreamError
from facedeform.common.parameters import PLACING_PARAMS
from facedeform.protocol.arith import Encoder
from facedeform.protocol.entropy import GroupState
from facedeform.protocol.framing import (
    DELTA,
    END,
    HEADER,
    KEY,
    MAX_BODY,
    MAX_COUNT,
    MAX_FRAME,
    MAX_REDUNDANCY,
    MODEL,
    PICTURE,
    SYNC,
    Delta,
    build,
    inner_check,
    kind_of,
    packet_ends,
    read_varint,
    type_byte,
    varint,
)
from facedeform.protocol.header import ID_BYTES, Header, encode_header
from facedeform.protocol.priors import models_for
from facedeform.protocol.quantise import DEAD_ZONE, hold_or_round

MODEL_CHUNK = 1024
PICTURE_PIECE = 1024  # bytes of a picture layer's payload per packet (and datagram)
#: Earlier frames packets a datagram carries again (Datagrams) by default: up to three lost in a row
#: cost no frame. On four dev clips' streams with a keyframe every 0.4 s, at 5 % loss in bursts of 3
#: datagrams, 94.3 % of frames were good with one copy, 94.7 % with two, 98.1 % with three
#: (docs/bitstream.md, "Bursts"), for 150, 214 and 264 bits a frame.
COPIES = 3
#: Keyframes: the header goes again before the first HEADER_EAGER, then every so many that its repeats
#: cost at most REPEAT_BITS a keyframe (333 bit/s with a keyframe every 0.24 s, fd-send over UDP), and at
#: least every HEADER_EVERY-th: the default layout's 49-byte header every 6th keyframe (a late joiner
#: waits 1.4 s), a speaker's own 213-byte one every 24th (5.8 s), a kilobyte header every 30th (7.2 s).
HEADER_EAGER, HEADER_EVERY, REPEAT_BITS = 10, 30, 80
#: fd-send over datagrams: the first EAGER_SECONDS of keyframes count as eager, and of them every one
#: EAGER_GAP seconds apart takes the header (sender.session). Before each of the first 10 keyframes, 0.24 s
#: apart, a speaker's own 203-byte header had cost 5.4 kbit/s over a 3-second call (6.8 while it lasted).
EAGER_SECONDS, EAGER_GAP = 4.0, 1.0
_MAX_INDEX = 1 << 30  # quantised values beyond this are a caller's bug (NaN, wrong units)
MAX_DEAD_ZONE = 4.0  # steps: beyond this a coarser quality level costs fewer bits for the same error


class PacketEncoder:
    """Packets of one stream. ``frames_per_packet`` (1-32) trades latency for framing bits.

    Packets never span a keyframe; with ``header.skip_static`` a frame equal to
    the previous does not count towards ``frames_per_packet``. ``dead_zone``
    (steps, 0.5-4; 0.5: plain rounding) bounds each coded value's error (each parameter's, or
    with the header's basis each coordinate's): see :func:`protocol.quantise.hold_or_round`.
    It holds across keyframes too, so a still value does not jump once a second. The receiver
    does not know it, so :attr:`dead_zone` may change between frames (``protocol.rate.RateKeeper``),
    and so may :attr:`frames_per_packet` and :attr:`key_every` (sender/link.py): a keyframe goes at
    every ``key_every``-th of the header's key places (a decoder takes a delta anywhere after a key;
    packets still end at every key place, since the decoder's rule for where a packet ends is fixed).
    :meth:`relevel` changes the quantiser level from the next frame on, which is then a keyframe.
    ``rounded``: placing parameters coded by plain rounding at the encoder's own dead zone (fd-send's
    head pose over a reference picture, fitted there to a fraction of a step: sender/session.py), held
    only by as much as :attr:`dead_zone` is later widened past it (``protocol.rate.RateKeeper``, keeping
    a rate the coarsest level does not fit).
    """

    def __init__(self, header: Header, frames_per_packet: int = 1, model: bytes = b"",
                 dead_zone: float = DEAD_ZONE, rounded: Sequence[str] = ()) -> None:
        if not 1 <= frames_per_packet <= MAX_COUNT:
            raise BitstreamError(f"frames per packet must be 1-{MAX_COUNT}")
        if len(model) != header.model_size:
            raise BitstreamError(f"header announces {header.model_size} model bytes, got {len(model)}")
        if any(n not in PLACING_PARAMS for n in rounded):  # (a coding basis keeps these on axes of their own)
            raise ValueError("only the placing parameters are coded by plain rounding")
        #: coordinates coded by plain rounding at the dead zone given here (the ``rounded`` parameters')
        self._rounded, self._own_zone = np.array([n in rounded for n in header.names]), dead_zone
        self._stream_header = self._h = header
        self.frames_per_packet, self._model = frames_per_packet, model
        self._relevel: Header | None = None  # the level the next keyframe goes at, where it changes
        self._relevel_at_place = False  # that keyframe waits for a key place
        self.level_changes = 0
        self.dead_zone = dead_zone
        self.key_every = 1
        self._new_bit = models_for(header)
        self._frames = 0
        self._held: list[int] | None = None
        #: (k,) float64 the decoder outputs for the last coded frame (None before one): exactly its Frame.params.
        self.reconstruction: np.ndarray | None = None
        self._group = GroupState(len(header.names), header.skip_static, self._new_bit)  # anew at each key
        self._coder: Encoder | None = None  # the pending packet's
        self._kind = self._first = self._count = 0

    @property
    def dead_zone(self) -> float:
        """Steps a coded value may stay from the parameter before it is sent again (0.5-4)."""
        return self._dead_zone

    @dead_zone.setter
    def dead_zone(self, steps: float) -> None:
        if not 0.5 <= steps <= MAX_DEAD_ZONE:
            raise BitstreamError(f"dead zone must be 0.5-{MAX_DEAD_ZONE:g} steps, not {steps!r}")
        self._dead_zone = steps

    def header(self, model: bool = True) -> list[bytes]:
        """The header packet, then (``model``) the face model in chunks."""
        chunks = [self.model_chunk(i, MODEL_CHUNK) for i in range(0, len(self._model), MODEL_CHUNK)] if model else []
        return [build(HEADER, encode_header(self._stream_header))] + chunks

    @property
    def level(self) -> int:
        """The quality level the last frame was coded at (the header's, unless :meth:`relevel` changed it)."""
        return self._h.quality

    def relevel(self, quality: int, at_place: bool = False) -> None:
        """Codes the frames from the next one on at quality level ``quality`` (the stream header at that
        level, :attr:`Header.levels`): the next frame is a keyframe that names it, and the packet pending
        ends before it; ``at_place``: from the next key place on, a keyframe there whatever
        :attr:`key_every` says (over datagrams, whose header repeats keep to the places). Asked again
        before it goes, it is the same change. ValueError if the header's steps are not a level's."""
        header = self._stream_header.at_level(quality)
        self._relevel = None if header is self._h else header
        self._relevel_at_place = at_place

    def model_chunk(self, offset: int, size: int) -> bytes:
        """The packet of the face model's bytes from ``offset``, at most ``size`` of them (1-MODEL_CHUNK);
        a decoder takes the chunks in order."""
        if not 0 <= offset < len(self._model) or not 1 <= size <= MODEL_CHUNK:
            raise ValueError(f"no model chunk of {size} bytes at {offset} (of {len(self._model)})")
        return build(MODEL, varint(offset) + self._model[offset:offset + size])

    def picture(self, frame: int, data: bytes) -> list[bytes]:
        """The picture layer's packets of its payload for frame ``frame`` (a frame number, of the
        frames given to :meth:`frame`): to go before the packet that carries it."""
        head = varint(frame // self._h.divisor) + varint(len(data))
        return [build(PICTURE, head + varint(i) + data[i:i + PICTURE_PIECE])
                for i in range(0, len(data), PICTURE_PIECE)]

    def frame(self, params: np.ndarray, face_seen: bool) -> list[bytes]:
        """(k,) float params in the header's layout; returns the packets this frame completes."""
        params = np.asarray(params, dtype=np.float64)
        if params.shape != self._h.steps.shape or not np.all(np.isfinite(params)):
            raise BitstreamError(f"expected {self._h.steps.size} finite parameters, got {params.shape}")
        index = self._frames
        if index // self._h.divisor >= MAX_FRAME:
            raise BitstreamError("stream too long: start a new one")
        self._frames += 1
        if index % self._h.divisor:
            return []
        coded = index // self._h.divisor
        place, off = divmod(coded, self._h.key_interval)
        key = off == 0 and place % self.key_every == 0
        ended = []  # the packet pending, where a new level's keyframe comes before its place
        if self._relevel is not None and (off == 0 or not self._relevel_at_place):
            key = True
            if self._coder is not None:
                ended.append(self._flush(self._coder, stop_flag=True))
            self._h, self._new_bit, self._held = self._relevel, models_for(self._relevel), None
            self._relevel, self.level_changes = None, self.level_changes + 1
        zone: float | np.ndarray = self._dead_zone
        if self._rounded.any():
            zone = np.where(self._rounded, 0.5 + max(0.0, zone - self._own_zone), zone)
        values = hold_or_round(self._h.coordinates(params), np.ones(len(params)), self._held, zone)
        if max(map(abs, values)) >= _MAX_INDEX:
            raise BitstreamError("parameter out of range for the stream's steps")
        self._held, self.reconstruction = values, self._h.values(values)
        face = bool(face_seen)
        if key:
            self._group = group = GroupState(len(values), self._h.skip_static, self._new_bit)
            coder = self._start(KEY, coded)
            group.encode_key(coder, values, face)
        else:
            group, pending = self._group, self._coder
            if pending is None:
                coder = self._start(DELTA, coded)
            else:
                coder = pending
                if self._kind == DELTA:
                    group.encode_more(coder, True)
            group.encode_delta(coder, values, face)
        self._count += 1
        implied = packet_ends(self._count, coded + 1, self._h.key_interval)
        if implied or group.active >= self.frames_per_packet:
            return ended + [self._flush(coder, stop_flag=not implied)]
        return ended

    def end(self) -> list[bytes]:
        """The last pending packet and the end mark."""
        pending = [] if self._coder is None else [self._flush(self._coder, stop_flag=True)]
        return pending + [build(END, varint(self._frames))]

    def _start(self, kind: int, coded: int) -> Encoder:
        """A new pending packet's coder."""
        self._coder = Encoder(SYNC)
        self._kind, self._first, self._count = kind, coded, 0
        return self._coder

    def _flush(self, coder: Encoder, stop_flag: bool) -> bytes:
        """The pending packet, whose coder is ``coder``; ``stop_flag``: the decoder cannot tell that it
        ends here (a delta packet then codes so)."""
        group, self._coder = self._group, None
        if self._kind == DELTA and stop_flag:
            group.encode_more(coder, False)
        group.end_packet()
        if self._kind == DELTA:
            head, covered = b"", self._first.to_bytes(4, "big")
        else:
            head = covered = bytes([type_byte(KEY, self._count)]) + self._h.ident + varint(self._first)
        value, bits = inner_check(self._kind, covered, coder.trace)
        for i in range(bits - 1, -1, -1):
            coder.bit(value >> i & 1)
        code = coder.end()
        if len(code) > MAX_BODY:
            raise BitstreamError(f"packet too large ({self._count} frames, {len(code)} bytes)")
        return bytes([SYNC]) + head + code if self._kind == KEY else Delta(code)


class StreamEncoder:
    """:class:`PacketEncoder` for byte streams: the same methods return bytes, as :func:`frame_bytes` frames them."""

    def __init__(self, header: Header, frames_per_packet: int = 1, model: bytes = b"",
                 dead_zone: float = DEAD_ZONE) -> None:
        self.packets = PacketEncoder(header, frames_per_packet, model, dead_zone)

    def header(self) -> bytes:
        return frame_bytes(self.packets.header())

    def frame(self, params: np.ndarray, face_seen: bool) -> bytes:
        """b"" while the frame waits in a packet (or is not sent at all)."""
        return frame_bytes(self.packets.frame(params, face_seen))

    def end(self) -> bytes:
        return frame_bytes(self.packets.end())


class Datagrams:
    """A :class:`PacketEncoder`'s packets made ready for a lossy datagram link (UDP), one datagram each.

    Redundancy as in RFC 2198: a frames packet's datagram first carries again
    the ``copies`` frames packets before it (a decoder skips those it holds,
    :meth:`protocol.decoder.PacketDecoder.packets`), so up to ``copies`` lost
    datagrams in a row cost no frame. Late join: the header
    packet goes again before every ``eager_every``-th of the first ``eager`` keyframes after the
    first and then before every ``header_every``-th (0: never; None: as often as
    REPEAT_BITS a keyframe pays for, at least every HEADER_EVERY-th; every HEADER_EVERY-th while
    :attr:`lean`), so a receiver started mid-call renders from the keyframe after it (but not with
    the stream's end: a receiver that joined then would draw a frame or two); the end mark goes
    twice. With a ``sealer`` every datagram is sealed, and the preamble goes again with the header.
    Given the header's ``key_interval``, keyframes are counted by their places (a keyframe's frame
    number over it), so that the header keeps its pace in time where the encoder sends a keyframe
    only at some places (:attr:`PacketEncoder.key_every`); once
    :attr:`joined`, the eager repeats stop. Model chunks are not repeated: a late receiver
    draws the face it has. What each costs is in docs/bitstream.md, "Datagrams".
    :attr:`copies` may change between packets: a decoder takes a datagram with any number.
    """

    def __init__(self, header_packet: bytes, copies: int = COPIES, header_every: int | None = None,
                 eager: int = HEADER_EAGER, sealer=None, eager_every: int = 1, key_interval: int | None = None
                 ) -> None:
        if not 0 <= copies <= MAX_REDUNDANCY:
            raise BitstreamError(f"redundancy must be 0-{MAX_REDUNDANCY} packets, not {copies!r}")
        self._header, self.copies, self._sealer = header_packet, copies, sealer
        if header_every is None:
            header_every = min(HEADER_EVERY, max(1, -(-8 * len(header_packet) // REPEAT_BITS)))
        self._every, self._eager, self._eager_every = header_every, eager, max(1, eager_every)
        self._recent: list[bytes] = []  # frames packets since the last keyframe, the newest last
        self._keys = 0
        self._last_key = -1  # the place of the last keyframe (-1: none yet)
        self._key_interval = key_interval
        #: The receiver reported (sender/link.py), so it holds the header: the eager repeats, for a
        #: receiver started a moment after the sender, stop; the later ones stay, for one that restarts.
        self.joined = False
        #: The receiver reports a link that loses nothing: the later repeats go at most every HEADER_EVERY-th
        #: keyframe place (one that restarts reports nothing until it holds the header: the spell ends).
        self.lean = False
        self.repeated = 0  # bytes of the header's repeats so far
        self.eager_repeated = 0  # of them, the bytes of the eager ones: those the later pace would not have sent

    def repeat_rate(self, key_seconds: float) -> float:
        """bit/s the header's repeats cost once the first ``eager`` keyframes (``key_seconds`` apart)
        are past (their sealing's few bytes aside)."""
        return 8 * len(self._header) / (self._every * key_seconds) if self._every else 0.0

    def eager_rate(self, key_seconds: float) -> float:
        """bit/s the header's repeats cost while the first ``eager`` keyframes go (the later ones'
        :meth:`repeat_rate` aside)."""
        return 8 * len(self._header) / (self._eager_every * key_seconds) if self._eager else 0.0

    def add(self, packets: list[bytes]) -> list[bytes]:
        """Datagrams for one step of the encoder (its header, a frame's packets or its end)."""
        out: list[bytes] = []
        ending = any(kind_of(packet) == END for packet in packets)
        for packet in packets:
            kind = kind_of(packet)
            if kind not in (KEY, DELTA, END):
                out += self._seal([packet])
                continue
            if kind == KEY:
                k, last = self._key_place(packet), self._last_key
                self._last_key = k
                if not ending and self._repeats(last, k):
                    repeat = self._seal([self._header], preamble=True)
                    self.repeated += sum(map(len, repeat))
                    if not self._repeats(last, k, eager=False):
                        self.eager_repeated += sum(map(len, repeat))
                    out += repeat
            copies = self._recent[-self.copies:] if self.copies else []
            while copies and sum(map(len, copies)) + len(packet) > MAX_BODY:
                copies = copies[1:]
            joined = b"".join(copies + [packet])
            out += self._seal([Delta(joined) if isinstance((copies or [packet])[0], Delta) else joined]
                              * (2 if kind == END else 1))
            if kind != END:
                self._recent = ([] if kind == KEY else self._recent[1 - MAX_REDUNDANCY:]) + [packet]
        return out

    def repeats_ahead(self, places: Iterable[int]) -> list[bool]:
        """Whether the header would go again before each keyframe at ``places`` (ascending, after the
        last one sent), as things stand (the sender's picture layer plans on them)."""
        out, last = [], self._last_key
        for place in places:
            out.append(self._repeats(last, place))
            last = place
        return out

    @property
    def repeat_size(self) -> int:
        """Bytes a repeat of the header takes (its sealing's few bytes aside)."""
        return len(self._header)

    def _repeats(self, last: int, place: int, eager: bool = True) -> bool:
        """Whether the header goes again before a keyframe at ``place`` after one at ``last`` (``eager``: the
        first ones' repeats counted)."""
        every = max(self._every, HEADER_EVERY) if self.lean and self._every else self._every
        eager = eager and not self.joined and place <= self._eager and _passes(self._eager_every, last, place)
        return place > 0 and (eager or (every > 0 and _passes(every, last, place)))

    def _key_place(self, packet: bytes) -> int:
        """The keyframe ``packet``'s place: its first frame's number over the key interval, or
        without one how many keyframes came before it."""
        if self._key_interval is None:
            self._keys += 1
            return self._keys - 1
        got = read_varint(packet, 2 + ID_BYTES, MAX_FRAME)  # after the sync, type and header id bytes
        assert got is not None, "a keyframe packet of the encoder's own"
        return got[0] // self._key_interval

    def _seal(self, datagrams: list[bytes], preamble: bool = False) -> list[bytes]:
        if self._sealer is None:
            return datagrams
        return ([self._sealer.preamble()] if preamble else []) + self._sealer.seal_all(datagrams)


def _passes(n: int, last: int, place: int) -> bool:
    """Whether a multiple of ``n`` lies after key place ``last`` and at or before ``place``."""
    return place // n > last // n


def frame_bytes(packets: list[bytes], sealed: bool = False) -> bytes:
    """Packets as they go on a byte stream: as the encoder returns them (a sync byte before each
    but a delta), end to end. ``sealed`` packets (protocol/secure.py) each get a sync byte."""
    if sealed:
        return b"".join(bytes([SYNC]) + p for p in packets)
    return b"".join(packets)


def stream_size(packets: list[bytes], sealed: bool = False) -> int:
    """``len(frame_bytes(packets, sealed))``, without joining them."""
    return sum(map(len, packets)) + (len(packets) if sealed else 0)
