"""Packets and their framing: type, length, check, and a sync byte for byte streams.

A packet is ``type-and-count byte | length varint | body | check``, except a
short delta: one byte for frame count and length, then ``body | check``. Deltas
are nearly every packet, and at 2-4 frames per packet their framing was a
quarter of the stream: on a byte stream a delta has no sync byte, and a short
one costs 16 bits instead of 32.

The check is as wide as what it guards is worth: CRC-32 for the header and
model chunks, CRC-16 for keyframes and the end mark, CRC-8 for delta packets. A
delta packet's CRC also covers the number of its first frame, which is not sent:
a delta is accepted only by a decoder that holds exactly the frames it was
predicted from, so a lost or repeated packet is caught without spending bits on
a sequence number.

On a byte stream (pipe, file, TCP) each packet but a delta is preceded by
:data:`SYNC`; a datagram carries one packet without it. A decoder that lost
sync finds it again at a sync byte, and only a keyframe restarts decoding
there, so deltas need none.

Version 6 drops the length of keyframe and delta packets and the delta's
first byte: their arithmetic code ends itself (``protocol.arith.Encoder.end``)
and carries the check as its last coded bits (:func:`inner_check`), so a delta
is nothing but its code. The code never starts with :data:`SYNC`, which is then
all a decoder needs to tell a delta from the rest; a version 6 datagram holds
the packet's byte-stream bytes, sync byte included.
"""

import binascii
import zlib
from dataclasses import dataclass

from common.errors import BitstreamError

SYNC = 0xFD
HEADER, MODEL, KEY, DELTA, END = range(5)
TYPE_NAMES = ("header", "model", "key", "delta", "end")
MAX_BODY = 4096  # longer than any valid packet: header with 64 names, 1 KiB model chunk, 32 keyframe frames
MAX_COUNT = 32  # frames per packet (5 bits)
_CHECK = {HEADER: 4, MODEL: 4, KEY: 2, DELTA: 1, END: 2}
SHORT = 0xA0  # first byte of a short delta: SHORT + SHORT_LENGTHS * (count - 1) + body length
SHORT_COUNT, SHORT_LENGTHS = 2, 46  # 1-2 frames (fd-send sends 2), bodies of 0-45 bytes: codes 0xA0-0xFB, never SYNC


def _crc8_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07 if crc & 0x80 else crc << 1) & 0xFF
        table.append(crc)
    return table


_CRC8 = _crc8_table()  # polynomial x^8 + x^2 + x + 1: every 1-3 bit error in a delta packet


def _crc(width: int, data: bytes) -> int:
    """The check of each width: CRC-32, CRC-16 (CCITT) or CRC-8."""
    if width == 4:
        return zlib.crc32(data)
    if width == 2:
        return binascii.crc_hqx(data, 0xFFFF)
    crc = 0
    for byte in data:
        crc = _CRC8[crc ^ byte]
    return crc


def _check(kind: int, data: bytes, first_frame: int) -> bytes:
    """A packet's trailing check; a delta's also covers its first frame number, which it does not carry."""
    width = _CHECK[kind]
    covered = first_frame.to_bytes(4, "big") + data if width == 1 else data
    return _crc(width, covered).to_bytes(width, "big")


def inner_check(kind: int, covered: bytes, trace: int) -> tuple[int, int]:
    """(value, bits) of a version 6 frames packet's check, coded inside its arithmetic code.

    It covers ``covered`` (a delta: its 4-byte first frame number; a keyframe
    packet: its bytes before the code) and ``trace``, every bit coded before it
    behind a leading 1 (:attr:`protocol.arith.Encoder.trace`): CRC-8 for a delta,
    CRC-16 for a keyframe packet, as in the older versions.
    """
    width = _CHECK[kind]
    return _crc(width, covered + trace.to_bytes((trace.bit_length() + 7) // 8, "big")), 8 * width


def varint(n: int) -> bytes:
    """Unsigned LEB128."""
    out = bytearray()
    while True:
        out.append((n & 0x7F) | (0x80 if n > 0x7F else 0))
        n >>= 7
        if not n:
            return bytes(out)


def read_varint(data: bytes, pos: int, limit: int) -> tuple[int, int] | None:
    """(value, next position), None if ``data`` ends first; BitstreamError above ``limit``."""
    value = shift = 0
    while pos < len(data):
        byte = data[pos]
        value |= (byte & 0x7F) << shift
        pos += 1
        if value > limit:
            raise BitstreamError(f"number {value} over its limit {limit}")
        if not byte & 0x80:
            return value, pos
        shift += 7
    return None


class Delta(bytes):
    """A version 6 delta packet: its first byte may be anything but :data:`SYNC`, so it says what
    it is by its type (:func:`protocol.encoder.frame_bytes` gives it no sync byte)."""


@dataclass(frozen=True)
class Packet:
    kind: int
    count: int  # frames in a key or delta packet, else 0
    body: bytes


def build(kind: int, body: bytes, count: int = 0, first_frame: int = 0) -> bytes:
    """One packet's bytes (no sync byte), a short delta where one fits; ``first_frame`` enters a
    delta packet's CRC only."""
    if not 0 <= count <= MAX_COUNT or len(body) > MAX_BODY:
        raise BitstreamError(f"packet too large ({count} frames, {len(body)} bytes)")
    if kind == DELTA and count <= SHORT_COUNT and len(body) < SHORT_LENGTHS:
        data = bytes([SHORT + SHORT_LENGTHS * (count - 1) + len(body)]) + body
    else:
        data = bytes([type_byte(kind, count)]) + varint(len(body)) + body
    return data + _check(kind, data, first_frame)


def type_byte(kind: int, count: int = 0) -> int:
    """A packet's first byte (a short delta's apart): its type in the top 3 bits and, in a keyframe
    or delta packet, its frame count less one in the low 5."""
    return kind << 5 | (count - 1 if count else 0)


def packet_type(first: int) -> int:
    """The type a first byte made by :func:`type_byte` says."""
    return first >> 5


def frame_count(first: int) -> int:
    """The frame count a keyframe or delta packet's first byte made by :func:`type_byte` says."""
    return (first & 0x1F) + 1


def packet_ends(count: int, next_frame: int, key_interval: int) -> bool:
    """Whether a frames packet of ``count`` frames ends before coded frame ``next_frame`` whatever
    the encoder wants: it is full, or that frame is a keyframe (version 6 codes no "more" flag then)."""
    return count == MAX_COUNT or next_frame % key_interval == 0


def is_short(first: int) -> bool:
    """Whether a packet starting with byte ``first`` is a short delta."""
    return SHORT <= first < SHORT + SHORT_COUNT * SHORT_LENGTHS


def is_delta(first: int) -> bool:
    """Whether a packet starting with byte ``first`` is a delta, short or long (no sync byte before it)."""
    return packet_type(first) == DELTA or is_short(first)


def _layout(data: bytes, pos: int) -> tuple[int, int, int, int] | None:
    """(kind, frame count, body start, body length) of the packet at ``data[pos]``, None if more
    bytes are needed to tell; BitstreamError when the first bytes cannot start a packet."""
    if pos >= len(data):
        return None
    first = data[pos]
    if is_short(first):
        count, n = divmod(first - SHORT, SHORT_LENGTHS)
        return DELTA, count + 1, pos + 1, n
    kind = packet_type(first)
    if kind not in _CHECK:
        raise BitstreamError(f"unknown packet type {kind}")
    length = read_varint(data, pos + 1, MAX_BODY)
    if length is None:
        return None
    n, body_start = length
    return kind, frame_count(first) if kind in (KEY, DELTA) else 0, body_start, n


def packet_size(data: bytes, pos: int) -> int | None:
    """Size of the packet starting at ``data[pos]``, None if more bytes are needed to tell.

    Raises BitstreamError when the first bytes cannot start a packet.
    """
    layout = _layout(data, pos)
    if layout is None:
        return None
    kind, _, body_start, n = layout
    return body_start - pos + n + _CHECK[kind]


def kind_of(packet: bytes) -> int:
    """The type of a packet as an encoder returns it: any version's, a version 6 one with its sync byte."""
    if isinstance(packet, Delta) or is_short(packet[0]):
        return DELTA
    return packet_type(packet[packet[0] == SYNC])


def body_bits(packet: bytes) -> int:
    """Bits of a packet as an encoder returns it, apart from its framing (sync and type bytes,
    length, check; a version 6 keyframe packet's frame number counts as body, as before)."""
    if isinstance(packet, Delta):
        return 8 * (len(packet) - _CHECK[DELTA])
    if packet[0] == SYNC:
        return 8 * (len(packet) - 2 - _CHECK[KEY])
    return 8 * _layout(packet, 0)[3]


def parse(data: bytes, expected_frame: int) -> Packet:
    """Checks one whole packet (no sync byte); a delta's CRC is checked against ``expected_frame``."""
    size = packet_size(data, 0)
    if size is None or size != len(data):
        raise BitstreamError("packet length does not match its length field")
    kind, count, body_start, _ = _layout(data, 0)
    width = _CHECK[kind]
    if _check(kind, data[:-width], expected_frame) != data[-width:]:
        raise BitstreamError(f"{TYPE_NAMES[kind]} packet fails its check")
    return Packet(kind, count, bytes(data[body_start:-width]))
