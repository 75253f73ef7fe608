"""The stream header: what a decoder must know before the first frame.

Binary, with every count and length bounded before anything is read or
allocated: a hostile header is refused, not obeyed.
"""

import hashlib
import struct
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from facedeform.common.errors import BitstreamError
from facedeform.common.limits import MAX_SIDE
from facedeform.common.parameters import PARAMETERS
from facedeform.protocol.basis import basis_matrices
from facedeform.protocol.framing import need_varint, varint
from facedeform.protocol.layouts import shipped, shipped_index
from facedeform.protocol.quantise import QUALITIES, dequantise, steps_for

MAGIC = b"FD"
#: The one version written and read; a decoder refuses any other (docs/bitstream.md, "Evolution").
VERSION = 20
MAX_NAMES = 64
MAX_NAME = 32
MAX_MODEL = 16 << 20  # bytes of pre-shared face model carried in-band
MAX_KEY_INTERVAL = 255
MAX_DIVISOR = 16
MAX_STEP = 1e6  # a quantiser step: any index times any step stays finite (|index| < 2**34)
#: Deformation rules a sender may assume (codec/model/deform.py), one byte on the wire: the index here.
RULES = ("refined", "paper")
_FLAG_F3_WITH_JAW, _FLAG_STATIC, _FLAG_BASIS = 1, 2, 4
#: The steps are the quality level's (protocol.quantise.steps_for) and are not written: 8 bytes a
#: parameter, half of a speaker's own layout's header (405 -> 213 bytes).
_FLAG_LEVEL_STEPS = 8
#: The names and the basis are a layout every package holds (protocol.layouts), named by its index
#: in one byte: the default layout's header 1,825 -> 65 bytes.
_FLAG_SHIPPED = 16
#: The in-band model starts with a preview face of ``preview_size`` bytes, a varint after ``model_size``
#: (a paced face, sender/face_pacing.py); a stream without one is written as before, byte for byte.
_FLAG_PREVIEW = 32
#: A byte after the preview's size: ``ahead``, how many frames a receiver waits for the picture layer's
#: next video frame (a stream without a picture layer, or that draws it from the past alone, writes none).
_FLAG_AHEAD = 64
_FLAGS = (_FLAG_F3_WITH_JAW | _FLAG_STATIC | _FLAG_BASIS | _FLAG_LEVEL_STEPS | _FLAG_SHIPPED | _FLAG_PREVIEW
          | _FLAG_AHEAD)
#: Frames a picture may wait for the layer's next video frame: fewer than the layer holds (frame_video.HELD).
MAX_AHEAD = 50
ID_BYTES = 4  # of a header's id, which every keyframe packet carries


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
    preview_size: of those, the first bytes that are a preview face (a face file of its own, drawn
    until the whole model has come; 0: none);
    width, height: the source's frame size in pixels (0: not given), the receiver's default
    output size; rule: the deformation rule the sender assumed, one of :data:`RULES`;
    ahead: frames (at most MAX_AHEAD) that a frame between two of the picture layer's video frames
    waits for the next one, which it is then drawn from as well (0: from the last alone);
    basis: (k, k) int8 coding axes (``protocol.basis``) or None: the coded values are then
    coordinates along the axes, in steps, instead of one value per parameter.

    A field out of range is ValueError (the caller's mistake); :func:`parse_header` reports a
    stream's as BitstreamError.
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
    width: int = 0
    height: int = 0
    rule: str = RULES[0]
    preview_size: int = 0
    ahead: int = 0

    def __post_init__(self) -> None:
        names, steps = self.names, np.asarray(self.steps, dtype=np.float64)
        if not (1 <= len(names) <= MAX_NAMES and all(1 <= len(n) <= MAX_NAME and n.isascii() for n in names)):
            raise ValueError(f"bad parameter layout: {names!r}")
        if steps.shape != (len(names),) or not np.all((steps > 0) & (steps <= MAX_STEP)):
            raise ValueError(f"quantiser steps must be one number in (0, {MAX_STEP:g}] per parameter")
        if not (0 < self.fps <= 1000 and 1 <= self.key_interval <= MAX_KEY_INTERVAL
                and 1 <= self.divisor <= MAX_DIVISOR and 0 <= self.model_size <= MAX_MODEL
                and 0 <= self.quality <= 255 and 0 <= self.width <= MAX_SIDE and 0 <= self.height <= MAX_SIDE
                and (self.preview_size == 0 or 0 < self.preview_size < self.model_size)
                and 0 <= self.ahead <= MAX_AHEAD):
            raise ValueError("header field out of range")
        if self.rule not in RULES:
            raise ValueError(f"unknown deformation rule {self.rule!r} (one of {', '.join(RULES)})")
        try:
            whole = len(bytes.fromhex(self.face_id)) == 32
        except (ValueError, TypeError):
            whole = False
        if not whole:
            raise ValueError("face id must be a sha256 hex string")
        object.__setattr__(self, "steps", steps)
        self._forward: np.ndarray
        self._inverse: np.ndarray
        if self.basis is not None:
            forward, inverse = basis_matrices(self.basis, len(names))
            object.__setattr__(self, "_forward", forward)
            object.__setattr__(self, "_inverse", inverse)

    def coordinates(self, params: np.ndarray) -> np.ndarray:
        """(k,) parameters -> (k,) coded coordinates in steps (indices are their rounding)."""
        u = np.asarray(params, dtype=np.float64) / self.steps
        return u if self.basis is None else u @ self._inverse

    def values(self, indices) -> np.ndarray:
        """k coded indices -> (k,) float64 parameters: what the decoder outputs."""
        if self.basis is None:
            return dequantise(indices, self.steps)
        return (np.asarray(indices, dtype=np.float64) @ self._forward) * self.steps

    @cached_property
    def ident(self) -> bytes:
        """The header's id, which every keyframe packet names: the first :data:`ID_BYTES` of the
        sha256 of its encoding. A receiver that holds the header (from an earlier call or a file)
        starts at a keyframe without waiting for the header to be sent again."""
        return hashlib.sha256(encode_header(self)).digest()[:ID_BYTES]

    @cached_property
    def levels(self) -> dict[bytes, "Header"]:
        """By id, this header at each quality level (itself among them) where its steps are its level's,
        else itself alone. A keyframe may name any of them, and the frames from it on take that level's
        steps: a sender whose call has grown livelier than the level it chose from its first second
        goes coarser mid-call (protocol/rate.py), at the cost of a keyframe, not a header."""
        if not _level_steps(self):
            return {self.ident: self}
        return {h.ident: h for h in (self if q == self.quality else replace(self, quality=q, steps=steps_for(
            self.names, q)) for q in QUALITIES)}

    def at_level(self, quality: int) -> "Header":
        """This header at quality level ``quality`` (one of :attr:`levels`); ValueError if it has none."""
        for header in self.levels.values():
            if header.quality == quality:
                return header
        raise ValueError(f"this header has no quality level {quality} (its steps are its own)")

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Header) and encode_header(self) == encode_header(other)


def _level_steps(h: Header) -> bool:
    """Whether ``h``'s steps are exactly its quality level's."""
    return (h.quality in QUALITIES and all(n in PARAMETERS for n in h.names)
            and np.array_equal(h.steps, steps_for(h.names, h.quality)))


def encode_header(h: Header) -> bytes:
    level, held = _level_steps(h), shipped_index(h.names, h.basis)
    written = h.basis is not None and held is None
    flags = (_FLAG_F3_WITH_JAW * h.f3_with_jaw | _FLAG_STATIC * h.skip_static | _FLAG_BASIS * written
             | _FLAG_LEVEL_STEPS * level | _FLAG_SHIPPED * (held is not None) | _FLAG_PREVIEW * bool(h.preview_size)
             | _FLAG_AHEAD * bool(h.ahead))
    out = bytearray(MAGIC + bytes([VERSION, flags, h.quality, h.key_interval, h.divisor, RULES.index(h.rule)]))
    out += varint(round(h.fps * 1000)) + varint(h.width) + varint(h.height)
    out += bytes.fromhex(h.face_id) + varint(h.model_size)
    if h.preview_size:
        out += varint(h.preview_size)
    if h.ahead:
        out.append(h.ahead)
    if held is not None:
        out.append(held)
    else:
        out.append(len(h.names))
        for name in h.names:
            out += bytes([len(name)]) + name.encode("ascii")
    if not level:
        out += struct.pack(f">{len(h.names)}d", *h.steps)
    if written and h.basis is not None:
        out += h.basis.tobytes()
    return bytes(out)


def parse_header(body: bytes) -> Header:
    """Header from a checked header packet's body; BitstreamError if it is not one we can read."""
    if len(body) < 9 or body[:2] != MAGIC:
        raise BitstreamError("input is not an fd stream (no fd header)")
    if body[2] != VERSION:
        raise BitstreamError(f"unsupported stream version {body[2]} (this decoder reads version {VERSION})")
    flags, quality, key_interval, divisor, rule = body[3:8]
    if rule >= len(RULES):
        raise BitstreamError(f"unknown deformation rule {rule}")
    if flags & ~_FLAGS or (flags & _FLAG_SHIPPED and flags & _FLAG_BASIS):
        raise BitstreamError(f"unknown header flags {flags:#04x}")
    fps_milli, pos = _varint(body, 8, 1_000_000)
    width, pos = _varint(body, pos, MAX_SIDE)
    height, pos = _varint(body, pos, MAX_SIDE)
    if pos + 32 > len(body):
        raise BitstreamError("stream header cut short")
    face_id = body[pos:pos + 32].hex()
    model_size, pos = _varint(body, pos + 32, MAX_MODEL)
    preview_size = 0
    if flags & _FLAG_PREVIEW:
        preview_size, pos = _varint(body, pos, MAX_MODEL)
        if not preview_size:  # written only when there is one: the same header would be written otherwise
            raise BitstreamError("stream header announces a preview of 0 bytes")
    ahead = 0
    if flags & _FLAG_AHEAD:
        ahead, pos = _byte(body, pos), pos + 1
        if not 0 < ahead <= MAX_AHEAD:
            raise BitstreamError(f"stream header asks pictures to wait {ahead} frames (1 to {MAX_AHEAD})")
    basis: np.ndarray | None = None
    if flags & _FLAG_SHIPPED:
        index, table = _byte(body, pos), shipped()
        if index >= len(table):
            raise BitstreamError(f"stream header names layout {index}, which this decoder does not hold")
        names, basis = list(table[index][0]), table[index][1]
        count, pos = len(names), pos + 1
    else:
        names, count, pos = _names(body, pos)
    basis_bytes = count * count if flags & _FLAG_BASIS else 0
    step_bytes = 0 if flags & _FLAG_LEVEL_STEPS else 8 * count
    if len(body) != pos + step_bytes + basis_bytes:
        raise BitstreamError("stream header length does not match its layout")
    if step_bytes:
        steps = np.array(struct.unpack(f">{count}d", body[pos:pos + step_bytes]))
    elif quality not in QUALITIES:
        raise BitstreamError(f"stream header takes the steps of quality level {quality}, which is none")
    elif not all(n in PARAMETERS for n in names):
        raise BitstreamError("stream header takes a quality level's steps for parameters without one")
    else:
        steps = steps_for(tuple(names), quality)
    if basis_bytes:
        basis = np.frombuffer(body, dtype=np.int8, count=basis_bytes, offset=pos + step_bytes).reshape(count, count)
    try:
        return Header(fps_milli / 1000, tuple(names), steps, face_id, bool(flags & _FLAG_F3_WITH_JAW), quality,
                      key_interval, divisor, bool(flags & _FLAG_STATIC), model_size, basis,
                      width, height, RULES[rule], preview_size, ahead)
    except ValueError as exc:
        raise BitstreamError(f"stream header: {exc}") from None


def _names(body: bytes, pos: int) -> tuple[list[str], int, int]:
    """(the parameter names written from ``pos``, their count, the position after them)."""
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
    return names, count, pos


def _varint(body: bytes, pos: int, limit: int) -> tuple[int, int]:
    return need_varint(body, pos, limit, "stream header cut short")


def _byte(body: bytes, pos: int) -> int:
    if pos >= len(body):
        raise BitstreamError("stream header cut short")
    return body[pos]
