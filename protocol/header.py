"""The stream header: what a decoder must know before the first frame.

Binary, with every count and length bounded before anything is read or
allocated: a hostile header is refused, not obeyed.
"""

import struct
from dataclasses import dataclass

import numpy as np

from common.errors import BitstreamError
from protocol.basis import basis_matrices
from protocol.framing import read_varint, varint
from protocol.quantise import dequantise

MAGIC = b"FD"
VERSION = 6
#: Version 2 differs only in framing (every packet long, and after a sync byte); version 4 adds a
#: coding basis to version 3's header; version 5 adds trained entropy models (protocol/entropy.py)
#: and carries a basis or not; version 6 is version 5 with keyframe and delta packets whose code
#: ends itself (no length field, the check inside the code). Versions 5, and 3 and 4, are still
#: written for ``Header(self_delimiting=False)`` and ``Header(trained=False)``.
READABLE = (2, 3, 4, 5, 6)
TRAINED_VERSION = 5
BASIS_VERSION = 4
MAX_NAMES = 64
MAX_NAME = 32
MAX_MODEL = 16 << 20  # bytes of pre-shared face model carried in-band
MAX_KEY_INTERVAL = 255
MAX_DIVISOR = 16
_FLAG_F3_WITH_JAW, _FLAG_STATIC, _FLAG_BASIS = 1, 2, 4


@dataclass(frozen=True, eq=False)
class Header:
    """Stream parameters.

    fps: frame rate of the source (the decoder outputs this rate);
    names: parameter layout, one name per value; steps: (k,) float64 quantiser
    steps; face_id: sha256 hex of the face model; quality: level the steps came
    from (0 if custom); key_interval: coded frames between keyframes; divisor:
    one frame in ``divisor`` is sent, the decoder interpolates the others;
    skip_static: frames equal to the previous cost a flag only; model_size:
    bytes of face model carried after the header (0: referenced by face_id only);
    basis: (k, k) int8 coding axes (``protocol.basis``) or None: the coded values are then
    coordinates along the axes, in steps, instead of one value per parameter;
    trained: the entropy models start from trained counts (version 5), else from
    nothing (versions 2-4, what older decoders read); self_delimiting: keyframe
    and delta packets end themselves (version 6; needs ``trained``, and is
    False whenever ``trained`` is). Sealed byte streams need packet lengths, so
    they use version 5.
    """

    fps: float
    names: tuple[str, ...]
    steps: np.ndarray
    face_id: str
    f3_with_jaw: bool = False
    quality: int = 3
    key_interval: int = 25
    divisor: int = 1
    skip_static: bool = False
    model_size: int = 0
    basis: np.ndarray | None = None
    trained: bool = True
    self_delimiting: bool = True

    def __post_init__(self) -> None:
        names, steps = self.names, np.asarray(self.steps, dtype=np.float64)
        if not (1 <= len(names) <= MAX_NAMES and all(1 <= len(n) <= MAX_NAME and n.isascii() for n in names)):
            raise BitstreamError(f"bad parameter layout: {names!r}")
        if steps.shape != (len(names),) or not np.all(np.isfinite(steps) & (steps > 0)):
            raise BitstreamError("quantiser steps must be one positive number per parameter")
        if not (0 < self.fps <= 1000 and 1 <= self.key_interval <= MAX_KEY_INTERVAL
                and 1 <= self.divisor <= MAX_DIVISOR and 0 <= self.model_size <= MAX_MODEL
                and 0 <= self.quality <= 255):
            raise BitstreamError("header field out of range")
        try:
            if len(bytes.fromhex(self.face_id)) != 32:
                raise ValueError
        except (ValueError, TypeError):
            raise BitstreamError("face id must be a sha256 hex string") from None
        object.__setattr__(self, "steps", steps)
        object.__setattr__(self, "self_delimiting", self.self_delimiting and self.trained)
        if self.basis is not None:
            forward, inverse = basis_matrices(self.basis, len(names))
            object.__setattr__(self, "_forward", forward)
            object.__setattr__(self, "_inverse", inverse)

    @property
    def version(self) -> int:
        if self.self_delimiting:
            return VERSION
        return TRAINED_VERSION if self.trained else 3 if self.basis is None else BASIS_VERSION

    def coordinates(self, params: np.ndarray) -> np.ndarray:
        """(k,) parameters -> (k,) coded coordinates in steps (indices are their rounding)."""
        u = np.asarray(params, dtype=np.float64) / self.steps
        return u if self.basis is None else u @ self._inverse

    def values(self, indices) -> np.ndarray:
        """k coded indices -> (k,) float64 parameters: what the decoder outputs."""
        if self.basis is None:
            return dequantise(indices, self.steps)
        return (np.asarray(indices, dtype=np.float64) @ self._forward) * self.steps

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Header) and encode_header(self) == encode_header(other)


def encode_header(h: Header) -> bytes:
    flags = _FLAG_F3_WITH_JAW * h.f3_with_jaw | _FLAG_STATIC * h.skip_static | _FLAG_BASIS * (h.basis is not None)
    out = bytearray(MAGIC + bytes([h.version, flags, h.quality, h.key_interval, h.divisor]))
    out += varint(round(h.fps * 1000)) + bytes.fromhex(h.face_id) + varint(h.model_size)
    out.append(len(h.names))
    for name in h.names:
        out += bytes([len(name)]) + name.encode("ascii")
    out += struct.pack(f">{len(h.names)}d", *h.steps)
    if h.basis is not None:
        out += h.basis.tobytes()
    return bytes(out)


def parse_header(body: bytes) -> Header:
    """Header from a checked header packet's body; BitstreamError if it is not one we can read."""
    if len(body) < 8 or body[:2] != MAGIC:
        raise BitstreamError("input is not an fd stream (no fd header)")
    if body[2] not in READABLE:
        raise BitstreamError(f"unsupported stream version {body[2]} (this decoder reads "
                             f"{', '.join(map(str, READABLE))})")
    flags, quality, key_interval, divisor = body[3:7]
    if body[2] < TRAINED_VERSION and bool(flags & _FLAG_BASIS) != (body[2] == BASIS_VERSION):
        raise BitstreamError(f"stream version {body[2]} with{'' if flags & _FLAG_BASIS else 'out'} a basis")
    fps_milli, pos = _varint(body, 7, 1_000_000)
    if pos + 32 > len(body):
        raise BitstreamError("stream header cut short")
    face_id = body[pos:pos + 32].hex()
    model_size, pos = _varint(body, pos + 32, MAX_MODEL)
    names = []
    count = _byte(body, pos)
    pos += 1
    if not 1 <= count <= MAX_NAMES:
        raise BitstreamError(f"stream header names {count} parameters")
    for _ in range(count):
        n = _byte(body, pos)
        if not 1 <= n <= MAX_NAME or pos + 1 + n > len(body):
            raise BitstreamError("stream header cut short")
        try:
            names.append(body[pos + 1:pos + 1 + n].decode("ascii"))
        except UnicodeDecodeError:
            raise BitstreamError("parameter name is not ASCII") from None
        pos += 1 + n
    basis_bytes = count * count if flags & _FLAG_BASIS else 0
    if len(body) != pos + 8 * count + basis_bytes:
        raise BitstreamError("stream header length does not match its layout")
    steps = np.array(struct.unpack(f">{count}d", body[pos:pos + 8 * count]))
    basis = None
    if basis_bytes:
        basis = np.frombuffer(body, dtype=np.int8, count=basis_bytes, offset=pos + 8 * count).reshape(count, count)
    return Header(fps_milli / 1000, tuple(names), steps, face_id, bool(flags & _FLAG_F3_WITH_JAW), quality,
                  key_interval, divisor, bool(flags & _FLAG_STATIC), model_size, basis,
                  body[2] >= TRAINED_VERSION, body[2] == VERSION)


def _varint(body: bytes, pos: int, limit: int) -> tuple[int, int]:
    got = read_varint(body, pos, limit)
    if got is None:
        raise BitstreamError("stream header cut short")
    return got


def _byte(body: bytes, pos: int) -> int:
    if pos >= len(body):
        raise BitstreamError("stream header cut short")
    return body[pos]
