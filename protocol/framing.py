"""Packets and their framing: type, check, and a sync byte for byte streams.

Every packet but a delta starts with :data:`SYNC`, then a byte whose top 3
bits are its type (:func:`type_byte`). The header, model chunks and the end
mark then carry a length and a trailing check::

    0xFD | type byte | length varint | body | check

Keyframe and delta packets carry no length: their arithmetic code ends itself
(``protocol.arith.Encoder.end``) and carries the check as its last coded bits
(:func:`inner_check`)::

    keyframe: 0xFD | type and frame count byte | first coded frame number varint | code
    delta:    code

A code never starts with :data:`SYNC`, which is all a decoder needs to tell a
delta from the rest; a decoder reads a delta only where the packet before it
ended. A datagram holds one packet's bytes exactly as on a byte stream.

The picture layer's packets (a payload of codec/render/frame_video.py, in pieces) are framed
like model chunks::

    0xFD | type byte | length varint | frame varint | total varint | offset varint | piece | check

The check is as wide as what it guards is worth: CRC-32 for the header and
model chunks, CRC-16 for keyframes, picture pieces and the end mark, CRC-8 for delta packets. A
delta's check also covers the number of its first frame, which is not sent: a
delta is accepted only by a decoder that holds exactly the frames it was
predicted from, so a lost or repeated packet is caught without spending bits on
a sequence number.
"""

import binascii
import zlib
from dataclasses import dataclass

from facedeform.common.errors import BitstreamError

SYNC = 0xFD
HEADER, MODEL, KEY, DELTA, END, PICTURE = range(6)
TYPE_NAMES = ("header", "model", "key", "delta", "end", "picture")
MAX_BODY = 4096  # longer than any valid packet: header with 64 names, 1 KiB model chunk, 32 keyframe frames
MAX_COUNT = 32  # frames per packet (5 bits)
MAX_REDUNDANCY = 3  # earlier frames packets a datagram may carry again (protocol.encoder.Datagrams)
MAX_DATAGRAM = MAX_BODY + 64  # bytes: no datagram of ours, sealed or not, is longer
MAX_FRAME = (1 << 32) - 1  # coded frame numbers (a delta's check covers 4 bytes of it): 5 years at 25 fps
_CHECK = {HEADER: 4, MODEL: 4, KEY: 2, DELTA: 1, END: 2, PICTURE: 2}
_FRAMED = (HEADER, MODEL, END, PICTURE)  # the packets with a length field


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


def inner_check(kind: int, covered: bytes, trace: int) -> tuple[int, int]:
    """(value, bits) of a frames packet's check, coded inside its arithmetic code.

    It covers ``covered`` (a delta: its 4-byte first frame number; a keyframe
    packet: its bytes before the code) and ``trace``, every bit coded before it
    behind a leading 1 (:attr:`protocol.arith.Encoder.trace`): CRC-8 for a delta,
    CRC-16 for a keyframe packet.
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


def need_varint(data: bytes, pos: int, limit: int, cut: str) -> tuple[int, int]:
    """(value, next position) as :func:`read_varint`, but BitstreamError(``cut``) if ``data`` ends first."""
    got = read_varint(data, pos, limit)
    if got is None:
        raise BitstreamError(cut)
    return got


class Delta(bytes):
    """A delta packet: its first byte may be anything but :data:`SYNC`, so it says what it is by
    its type (:func:`protocol.encoder.frame_bytes` gives it no sync byte)."""


@dataclass(frozen=True)
class Packet:
    """A checked header, model or end packet."""

    kind: int
    body: bytes


def build(kind: int, body: bytes) -> bytes:
    """A header, model, end or picture packet's bytes, sync byte first."""
    if kind not in _FRAMED or len(body) > MAX_BODY:
        raise BitstreamError(f"cannot frame a {TYPE_NAMES[kind]} packet of {len(body)} bytes")
    data = bytes([type_byte(kind)]) + varint(len(body)) + body
    return bytes([SYNC]) + data + _crc(_CHECK[kind], data).to_bytes(_CHECK[kind], "big")


def type_byte(kind: int, count: int = 0) -> int:
    """A packet's byte after its sync byte: its type in the top 3 bits and, in a keyframe packet,
    its frame count less one in the low 5."""
    return kind << 5 | (count - 1 if count else 0)


def packet_type(first: int) -> int:
    """The type a byte made by :func:`type_byte` says."""
    return first >> 5


def frame_count(first: int) -> int:
    """The frame count a keyframe packet's type byte says."""
    return (first & 0x1F) + 1


def packet_ends(count: int, next_frame: int, key_interval: int) -> bool:
    """Whether a frames packet of ``count`` frames ends before coded frame ``next_frame`` whatever
    the encoder wants: it is full, or that frame is a keyframe (a delta codes no "more" flag then)."""
    return count == MAX_COUNT or next_frame % key_interval == 0


def _framing(data: bytes, pos: int) -> tuple[int, int, int] | None:
    """(type, body start, body length) of the header, model or end packet whose type byte is
    ``data[pos]``, None if more bytes are needed to tell; BitstreamError if it cannot be one."""
    if pos >= len(data):
        return None
    kind = packet_type(data[pos])
    if kind not in _FRAMED or data[pos] & 0x1F:
        raise BitstreamError(f"no length-framed packet of type {kind}")
    length = read_varint(data, pos + 1, MAX_BODY)
    return None if length is None else (kind, length[1], length[0])


def packet_size(data: bytes, pos: int) -> int | None:
    """Size of the header, model or end packet whose type byte is ``data[pos]`` (sync byte
    excluded), None if more bytes are needed to tell.

    Raises BitstreamError when the bytes cannot start such a packet.
    """
    framing = _framing(data, pos)
    if framing is None:
        return None
    kind, body_start, n = framing
    return body_start - pos + n + _CHECK[kind]


def kind_of(packet: bytes) -> int:
    """The type of a packet as an encoder returns it."""
    return DELTA if isinstance(packet, Delta) else packet_type(packet[1])


def body_bits(packet: bytes) -> int:
    """Bits of a keyframe or delta packet as the encoder returns it, apart from its framing (sync and
    type bytes, the check coded inside; a keyframe packet's frame number counts as body)."""
    if isinstance(packet, Delta):
        return 8 * (len(packet) - _CHECK[DELTA])
    return 8 * (len(packet) - 2 - _CHECK[KEY])


def parse(data: bytes) -> Packet:
    """Checks one whole header, model or end packet (from its type byte: no sync byte)."""
    framing = _framing(data, 0)
    if framing is None or framing[1] + framing[2] + _CHECK[framing[0]] != len(data):
        raise BitstreamError("packet length does not match its length field")
    kind, body_start, _ = framing
    width = _CHECK[kind]
    if _crc(width, data[:-width]).to_bytes(width, "big") != data[-width:]:
        raise BitstreamError(f"{TYPE_NAMES[kind]} packet fails its check")
    return Packet(kind, bytes(data[body_start:-width]))
