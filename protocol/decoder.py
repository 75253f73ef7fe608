"""Packets or bytes in, events out; damage is reported and survived, never raised.

After a valid header nothing a link can do to the bytes raises: a packet that
fails its check, cannot be decoded, or does not follow the frames held is
dropped with a :class:`Damage` event, frames are concealed until the next
keyframe, and :attr:`stats` counts it all. Only a stream that never was one (no
header, another version) raises :class:`BitstreamError`.

Nothing from the wire sizes a loop or an allocation unchecked: a keyframe or
an end mark may claim frames beyond the next one expected only as far as the
bytes received since the last accepted frames packet could have carried
(:meth:`PacketDecoder.allowance`), so the frames a decoder emits, concealed ones
included, are paid for by received bytes (docs/security.md, "Bounds").
"""

from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from facedeform.common.errors import BitstreamError
from facedeform.protocol.arith import Decoder, Incomplete
from facedeform.protocol.entropy import GroupState
from facedeform.protocol.events import Damage, End, Frame, Model, Picture, Stats
from facedeform.protocol.framing import (
    DELTA,
    END,
    HEADER,
    KEY,
    MAX_BODY,
    MAX_COUNT,
    MAX_DATAGRAM,
    MAX_FRAME,
    MAX_REDUNDANCY,
    MODEL,
    PICTURE,
    SYNC,
    frame_count,
    inner_check,
    need_varint,
    packet_ends,
    packet_size,
    packet_type,
    parse,
    read_varint,
)
from facedeform.protocol.header import ID_BYTES, Header, parse_header
from facedeform.protocol.model_parts import ModelParts
from facedeform.protocol.priors import models_for

MAX_PICTURE = 1 << 18  # bytes of one picture layer payload: far more than any rate asks for
MAX_SEEK = 1 << 16  # bytes searched for a header before the input is declared foreign


@dataclass(frozen=True)
class Read:
    """What the bytes at a position came to: ``used`` > 0, a packet of that many bytes was read
    (its ``events``, none for a copy already taken); ``used`` 0, none was, and ``wait`` says
    whether more bytes may make one (never once the input has ended) or none is here."""

    events: list = field(default_factory=list)
    used: int = 0
    wait: bool = False


_NONE_HERE = Read()
_WAIT = Read(wait=True)


class PacketDecoder:
    """Whole packets in, events out: the core that the datagram, byte-stream and sealed decoders
    feed (:class:`DatagramDecoder`, :class:`StreamDecoder`, ``protocol.secure_stream``).

    A datagram holds one packet as on a byte stream (:meth:`accept_wire`): a
    sync byte before each packet but a delta; a delta's datagram may carry the
    packets before it again first (:meth:`packets`). ``known``: headers the
    receiver holds already (an earlier call, a file): a keyframe that names one
    starts the stream without its header packet. ``late_join``: the first
    keyframe may start the output wherever it is (a datagram receiver started
    mid-call); a byte stream always starts at its beginning.
    """

    def __init__(self, known: Iterable[Header] = (), late_join: bool = False) -> None:
        self.header: Header | None = None
        self._known = {ident: h for h in known for ident in h.levels}  # a keyframe may name any level of one
        self._late_join = late_join
        self._start = 0  # the first frame output
        # the last frames packets accepted: a datagram's copies (picture and header packets between them
        # pushed out a keyframe whose copy, decoded again, then broke the delta after it)
        self._recent: deque[bytes] = deque(maxlen=MAX_REDUNDANCY + 1)
        self.stats = Stats()
        self.ended = False
        self._group: GroupState | None = None  # None: waiting for a keyframe
        self._level: Header | None = None  # the header at the level the last keyframe named (Header.levels)
        #: While waiting for a keyframe, damage is not reported: it was already (or a late joiner waits for its first).
        self._quiet = late_join
        self._next = 0  # coded index the next delta packet must start at
        self._out = 0  # next output frame number
        self._last: tuple[int, np.ndarray, bool] | None = None  # coded index, params, face of the last decoded
        self._model: ModelParts | None = None  # the in-band face model, from its first chunk
        self._model_held = False  # the receiver holds the face model already (hold_model)
        self._picture: tuple[int, int, bytearray] | None = None  # (frame, total, bytes so far)
        self._previous = b""
        self._position = 0  # bytes of input (junk and damage included) before the packet being read
        self._paid = 0  # where the last accepted frames packet ended

    def unpaid(self, size: int) -> int:
        """Bytes received since the last accepted frames packet, up to the end of the packet of
        ``size`` bytes being read."""
        return self._position + size - self._paid

    @property
    def _header(self) -> Header:
        """The header, where a packet is decoded: only packets after one are."""
        if self.header is None:
            raise BitstreamError("a packet before the stream's header")
        return self.header

    def allowance(self, size: int) -> int:
        """Coded frames a keyframe or end mark of ``size`` bytes may lie beyond the next one expected:
        :data:`~protocol.framing.MAX_COUNT` per byte :meth:`unpaid` (the frames between were in
        packets of at most that many frames and at least a byte)."""
        return MAX_COUNT * self.unpaid(size)

    def packet(self, data: bytes, at: int) -> list:
        """Events of one datagram's packets (:meth:`packets`), ``at`` bytes into the input; a bad
        one is dropped and reported."""
        events = self.packets(data, at)
        return self.damage("packet fails its check or cannot be decoded") if events is None else events

    def packets(self, data: bytes, at: int) -> list | None:
        """Events of the packets of one datagram that starts ``at`` bytes into the input (junk and
        damage included: what pays for frames), as on a byte stream; None (nothing changed) if none
        can be read here. Packets the decoder accepted last are skipped: a frames packet's datagram
        carries the packets before it again (``protocol.encoder.Datagrams``), so whichever of them
        were lost are decoded from the copies, in order. A packet that cannot be read here (a copy
        from before a late join) is passed over to the next sync byte: every packet but a delta
        starts with one, and a keyframe or framed packet is checked before it is decoded."""
        data = bytes(data)
        events: list = []
        pos, accepted, repeated, fresh = 0, False, True, 0
        started = self._last is not None  # (a late joiner's first frames, copies or not, repair nothing)
        while pos < len(data):
            repeat = next((len(r) for r in self._recent if data.startswith(r, pos)), 0)
            if repeat:
                pos += repeat
                continue
            got = self.accept_wire(data, pos, True, at + pos)
            if not got.used:  # a copy this decoder cannot use: try the next sync byte
                pos, repeated = data.find(SYNC, pos + 1), False
                if pos < 0:
                    break
                continue
            if data[pos] != SYNC or packet_type(data[pos + 1]) == KEY:  # a frames packet: what copies repeat
                self._recent.append(data[pos:pos + got.used])
                fresh += any(isinstance(e, Frame) for e in got.events)
            accepted = True
            events += got.events
            pos += got.used
        if not accepted:
            if not (repeated and data):
                return None
            self.stats.duplicates += 1  # a datagram of packets all taken before
        if started:
            self.stats.repaired += max(0, fresh - 1)  # a datagram brings one frames packet of its own
        return events

    def accept_wire(self, buf: bytes, pos: int, final: bool, at: int) -> Read:
        """The packet at ``buf[pos]``, ``at`` bytes into the input; ``final``: ``buf`` ends where the
        stream or datagram does."""
        self._position = at
        if buf[pos] != SYNC:
            return self._self_delimited(buf, pos, final, DELTA)
        if pos + 1 >= len(buf):
            return _NONE_HERE if final else _WAIT
        if packet_type(buf[pos + 1]) == KEY:
            got = self._self_delimited(buf, pos + 1, final, KEY)
            return Read(got.events, got.used + 1) if got.used else got
        try:
            size = packet_size(buf, pos + 1)
        except BitstreamError:
            return _NONE_HERE
        if size is None or pos + 1 + size > len(buf):
            return _NONE_HERE if final else _WAIT
        events = self._framed(bytes(buf[pos + 1:pos + 1 + size]))
        return _NONE_HERE if events is None else Read(events, 1 + size)

    def _framed(self, data: bytes) -> list | None:
        """Events of a header, model or end packet (from its type byte), None if not valid here."""
        try:
            packet = parse(data)
        except BitstreamError:
            if data == self._previous:
                self.stats.duplicates += 1
                return []
            return None
        if self.header is None and packet.kind != HEADER:
            return None
        try:
            if packet.kind == HEADER:
                events = self._on_header(packet.body)
            elif packet.kind == MODEL:
                events = self._on_model(packet.body)
            elif packet.kind == PICTURE:
                events = self._on_picture(packet.body)
            else:
                events = self._on_end(packet.body, 1 + len(data))
        except BitstreamError:
            if packet.kind == HEADER:
                raise
            return None
        if events is not None:
            self.stats.packets += 1
            self._previous = data
        return events

    def _self_delimited(self, buf: bytes, pos: int, final: bool, kind: int) -> Read:
        """A keyframe packet (from its type byte) or delta packet at ``buf[pos]``."""
        if self.header is None and not (kind == KEY and self._known):
            return _NONE_HERE
        try:
            got = self._key(buf, pos) if kind == KEY else self._delta(buf, pos)
        except Incomplete:
            return _NONE_HERE if final or len(buf) - pos > MAX_BODY + 8 else _WAIT
        except BitstreamError:
            got = None
        if got is None:
            previous = self._previous
            if previous and bytes(buf[pos:pos + len(previous)]) == previous:
                self.stats.duplicates += 1
                return Read([], len(previous))
            return _NONE_HERE
        events, data = got
        self.stats.packets += 1
        self._previous = data
        return Read(events, len(data))

    def _key(self, buf: bytes, pos: int) -> tuple[list, bytes] | None:
        count = frame_count(buf[pos])
        ident = bytes(buf[pos + 1:pos + 1 + ID_BYTES])
        got = read_varint(buf, pos + 1 + ID_BYTES, MAX_FRAME)
        if got is None:
            raise Incomplete
        stream = self.header if self.header is not None else self._known.get(ident)
        header = None if stream is None else stream.levels.get(ident)
        if stream is None or header is None:
            return None  # another stream's, or one whose header has not arrived
        coded, start = got
        dec = Decoder(bytes(buf[start:start + MAX_BODY]), SYNC)
        group = GroupState(len(header.names), header.skip_static, models_for(header))
        decoded = [group.decode_key(dec)] + [group.decode_delta(dec) for _ in range(count - 1)]
        data = self._checked(dec, KEY, bytes(buf[pos:start]), buf, pos, start)
        if data is None:
            return None
        started = []
        if self.header is None:
            self.header, started = stream, [stream]
        if coded < self._next or self.ended:
            self.stats.duplicates += 1
            return [], data
        size = len(data) + 1  # and the sync byte
        if self._late_join and self._last is None:  # nothing output yet: start here
            self._next, self._out = coded, coded * header.divisor
            self._start = self._out
        if coded - self._next > self.allowance(size):
            return self.damage(f"keyframe {coded} is {coded - self._next} frames ahead, more than the "
                               f"{self.unpaid(size)} bytes since the last frames allow", always=True), data
        events = self.damage("packets lost before a keyframe") if coded > self._next else []
        group.end_packet()
        self._group, self._level, self._paid = group, header, self._position + size
        return started + events + self._emit(coded, decoded), data

    def _delta(self, buf: bytes, pos: int) -> tuple[list, bytes] | None:
        if self._group is None or self.ended:
            return None
        group, dec = self._group, Decoder(bytes(buf[pos:pos + MAX_BODY]), SYNC)
        saved, dec.journal = group.state(), []  # the group changes only if the packet passes its check
        try:
            decoded, interval = [], self._header.key_interval
            while True:
                decoded.append(group.decode_delta(dec))
                if packet_ends(len(decoded), self._next + len(decoded), interval):
                    break
                if not group.decode_more(dec):
                    break
            data = self._checked(dec, DELTA, self._next.to_bytes(4, "big"), buf, pos, pos)
        except (Incomplete, BitstreamError):
            group.restore(saved, dec.journal)
            raise
        if data is None:
            group.restore(saved, dec.journal)
            return None
        group.end_packet()
        self._paid = self._position + len(data)
        return self._emit(self._next, decoded), data

    @staticmethod
    def _checked(dec: Decoder, kind: int, covered: bytes, buf: bytes, pos: int, start: int) -> bytes | None:
        """The packet's bytes if the check coded after its frames holds and its code is the
        encoder's own (``start``: where the code begins), else None."""
        value, bits = inner_check(kind, covered, dec.trace)
        got = 0
        for _ in range(bits):
            got = got << 1 | dec.bit()
        code = dec.end()
        if got != value or bytes(buf[start:start + len(code)]) != code:
            return None
        return bytes(buf[pos:start + len(code)])

    def damage(self, reason: str, always: bool = False) -> list:
        """Records damage; reported once per loss of sync (unless ``always``), then frames wait for a
        keyframe. Damage before the first keyframe is reported too (a byte stream's first packets)."""
        if self._group is None and self._quiet and not always:
            return []
        self._group, self._quiet = None, True
        self.stats.damaged += 1
        self.stats.reasons.append(reason)
        return [Damage(self._out, reason)]

    def _on_header(self, body: bytes) -> list | None:
        header = parse_header(body)
        if self.header is not None:
            if header != self.header:
                return None
            self.stats.duplicates += 1
            return []
        self.header = header
        return [header]

    def _on_model(self, body: bytes) -> list | None:
        """A chunk of the face model, from anywhere in it (a paced face goes round over datagrams:
        protocol/model_parts.py); the preview and the face are each one event, once."""
        header = self._header
        got = read_varint(body, 0, header.model_size)
        if got is None:
            return None
        offset, pos = got
        if self._model_held or not body[pos:]:
            self.stats.duplicates += 1
            return []
        parts = self._model = self._model or ModelParts(header.model_size)
        had = parts.missing
        added = parts.add(offset, body[pos:])
        if added is None:
            return None
        if not added:
            self.stats.duplicates += 1
            return []
        preview = header.preview_size
        events = [Model(parts.bytes(preview), preview=True)] if had < preview <= parts.missing else []
        if parts.whole:
            events.append(Model(parts.bytes()[preview:]))
        return events

    def hold_model(self) -> None:
        """The receiver holds the stream's face model already (by its id): its chunks are passed over,
        and :attr:`model_missing` says it is whole."""
        self._model_held = True

    @property
    def model_missing(self) -> int:
        """The first byte of the stream's face model not held (what a receiver reports back, so that a
        paced face's sender goes on from there): its size once it is held, or none is carried; 0
        before the header."""
        if self.header is None:
            return 0
        size = self.header.model_size
        return size if self._model_held or not size else (0 if self._model is None else self._model.missing)

    def _on_picture(self, body: bytes) -> list | None:
        """A piece of a picture layer's payload: pieces come in order, one payload at a time (a new
        frame's first piece drops an unfinished one); the whole payload is one event."""
        cut = "picture packet ends inside a number"
        frame, pos = need_varint(body, 0, MAX_FRAME, cut)
        total, pos = need_varint(body, pos, MAX_PICTURE, cut)
        offset, pos = need_varint(body, pos, MAX_PICTURE, cut)
        piece = body[pos:]
        if not piece or offset + len(piece) > total:
            return None
        held = self._picture
        if held is not None and held[0] == frame and held[1] == total and offset < len(held[2]):
            self.stats.duplicates += 1
            return []
        if offset == 0:
            held = self._picture = (frame, total, bytearray())
        if held is None or (held[0], held[1], len(held[2])) != (frame, total, offset):
            return []  # a piece of a payload whose start was lost: it cannot be used
        held[2].extend(piece)
        if len(held[2]) < total:
            return []
        self._picture = None
        return [Picture(frame * self._header.divisor, bytes(held[2]))]

    def _on_end(self, body: bytes, size: int) -> list | None:
        divisor = self._header.divisor
        try:
            got = read_varint(body, 0, MAX_FRAME * divisor)
        except BitstreamError:
            return self.damage("end mark claims more frames than a stream can hold", always=True)
        if got is None or got[1] != len(body):
            return None
        if self.ended:
            self.stats.duplicates += 1
            return []
        total = got[0]
        coded = -(-total // divisor)
        if total < self._out or coded - self._next > self.allowance(size):
            return self.damage(f"end mark claims {total} frames: {self._out} were output, and the "
                               f"{self.unpaid(size)} bytes since the last frames allow no more than "
                               f"{(self._next + self.allowance(size)) * divisor}", always=True)
        complete = self._next == coded and (self._group is not None or coded == 0)  # or a stream of no frames
        events = [] if complete else self.damage("packets lost before the end mark")
        events += self._fill(total, None, complete)
        self.ended = True
        return events + [End(total - self._start)]

    def _emit(self, coded: int, decoded: list[tuple[list[int], bool]]) -> list:
        events, level = [], self._level
        assert level is not None, "frames come after a keyframe"
        for c, (values, face) in enumerate(decoded, coded):
            params = level.values(values)
            frame = c * self._header.divisor
            events += self._fill(frame, (c, params))
            events.append(Frame(frame, params, face))
            self._last, self._out = (c, params, face), frame + 1
        self._next = coded + len(decoded)
        return events

    def _fill(self, until: int, target: tuple[int, np.ndarray] | None, complete: bool = False) -> list:
        """Frames from the next one up to ``until``: interpolated towards ``target`` if it follows the
        last decoded frame directly, held after the last frame of a ``complete`` stream, else
        concealed: interpolated towards ``target`` over the frames lost between, else held."""
        events = []
        if self._last is None:
            held, face, start = np.zeros(len(self._header.names)), False, None
        else:
            start, held, face = self._last
        divisor = self._header.divisor
        for f in range(self._out, until):
            if complete:
                events.append(Frame(f, held, face, interpolated=True))
            elif target is not None and start is not None and target[0] == start + 1:  # follows directly
                t = (f - start * divisor) / divisor
                events.append(Frame(f, held + t * (target[1] - held), face, interpolated=True))
            elif target is not None and start is not None:  # lost frames between two decoded ones
                t = (f - start * divisor) / ((target[0] - start) * divisor)
                events.append(Frame(f, held + t * (target[1] - held), face, concealed=True))
                self.stats.concealed += 1
            else:
                events.append(Frame(f, held, False, concealed=True))
                self.stats.concealed += 1
        self._out = max(self._out, until)
        return events


class DatagramDecoder(PacketDecoder):
    """One datagram at a time (:meth:`receive`, in arrival order); may join a stream late.

    A datagram that cannot be read here is dropped and counted in
    ``stats.skipped_bytes``, not reported as damage: on a socket it may not be
    ours at all, and a lost packet of ours shows at the next keyframe. What
    :func:`could_start` refuses costs no decoding work.
    """

    def __init__(self, known: Iterable[Header] = ()) -> None:
        super().__init__(known, late_join=True)
        self._received = 0  # bytes of every datagram before this one

    def receive(self, data: bytes) -> list:
        events = self.packets(data, self._received) if self.could_start(data) else None
        if events is None:
            self.stats.skipped_bytes += len(data)
            events = []
        self._received += len(data)
        return events

    def could_start(self, data: bytes) -> bool:
        """Whether ``data`` may start a datagram this decoder can use now, from its first two bytes:
        before a header only a header (or a keyframe naming a known one), and a code never starts
        with 0xFE or 0xFF."""
        if not 0 < len(data) <= MAX_DATAGRAM:
            return False
        if data[0] != SYNC:  # a delta, or copies of deltas before a keyframe
            return self.header is not None and data[0] < SYNC
        kind = packet_type(data[1]) if len(data) > 1 else -1
        if self.header is None:
            return kind == HEADER or (kind == KEY and bool(self._known))
        return kind in (HEADER, MODEL, KEY, END, PICTURE)


class WrapsPacketDecoder:
    """What a decoder built around a :class:`PacketDecoder` (``self._core``) shows of it."""

    _core: PacketDecoder

    @property
    def header(self) -> Header | None:
        return self._core.header

    @property
    def stats(self) -> Stats:
        return self._core.stats

    @property
    def ended(self) -> bool:
        return self._core.ended

    @property
    def model_missing(self) -> int:
        return self._core.model_missing

    def hold_model(self) -> None:
        self._core.hold_model()


class ByteStreamDecoder(WrapsPacketDecoder):
    """Incremental decoding of a byte stream: :meth:`feed` any chunking, :meth:`close` at its end.

    Subclasses scan their buffer (``_scan``) and say why no stream was found (``_no_stream``).
    """

    def __init__(self) -> None:
        self._core = PacketDecoder()
        self._buf = bytearray()
        self._base = 0  # bytes fed before the buffer's first

    def feed(self, data: bytes) -> list:
        """Events completed by ``data``."""
        self._buf += data
        return self._scan(final=False)

    def close(self) -> list:
        """Events still in the buffer, then a :class:`Damage` if the stream stopped before its end mark.

        Raises BitstreamError if the input held no stream at all.
        """
        events = self._scan(final=True)
        if self._core.header is None:
            raise BitstreamError(self._no_stream())
        if not self._core.ended:
            events += self._core.damage("stream stopped before its end mark", always=True)
        return events

    def _scan(self, final: bool) -> list:
        events, buf, pos = [], self._buf, 0
        while pos < len(buf):
            if not self._starts_packet(pos):
                start = pos
                pos = buf.find(SYNC, pos)
                pos = len(buf) if pos < 0 else pos
                events += self._skip(pos - start, "bytes between packets")
                continue
            step = self._packet_at(pos, final)
            if step is None:
                break  # wait for the rest: a packet is at most MAX_BODY plus a few bytes
            got, used = step
            events += got
            pos += used
        del buf[:pos]
        self._base += pos
        return events

    def _starts_packet(self, pos: int) -> bool:
        return self._buf[pos] == SYNC

    def _packet_at(self, pos: int, final: bool) -> tuple[list, int] | None:
        """Events of the packet that starts at ``pos`` (sync byte included, ``self._base + pos`` bytes
        into the input) and the bytes used; None to wait."""
        raise NotImplementedError

    def _no_stream(self) -> str:
        raise NotImplementedError

    def _skip(self, n: int, reason: str) -> list:
        """Events of ``n`` bytes passed over while looking for a packet."""
        raise NotImplementedError


class StreamDecoder(ByteStreamDecoder):
    """The clear format's byte-stream decoder.

    A delta has no sync byte: it is read only where the packet before it ended,
    never while looking for sync.
    """

    def __init__(self) -> None:
        super().__init__()
        self._synced = False  # the buffer starts where the last accepted packet ended

    def _starts_packet(self, pos: int) -> bool:
        return self._buf[pos] == SYNC or (self._synced and self._core.header is not None)

    def _no_stream(self) -> str:
        if not self._base + len(self._buf):
            return "empty input: no fd stream"
        return "input is not an fd stream (no valid header)"

    def _packet_at(self, pos: int, final: bool) -> tuple[list, int] | None:
        got = self._core.accept_wire(self._buf, pos, final, self._base + pos)
        if got.wait:
            return None
        if not got.used:
            return self._skip(1, "packet fails its check or cannot be decoded"), 1
        self._synced = True
        return got.events, got.used

    def _skip(self, n: int, reason: str) -> list:
        self._synced = False
        self._core.stats.skipped_bytes += n
        if self._core.header is None:
            if self._core.stats.skipped_bytes > MAX_SEEK:
                raise BitstreamError(f"input is not an fd stream (no header in its first {MAX_SEEK} bytes)")
            return []
        return self._core.damage(reason)
