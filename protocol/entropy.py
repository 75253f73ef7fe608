"""Residual coding of parameter frames: closed-loop prediction plus adaptive contexts.

Each value is predicted by the previous reconstructed value of the same
parameter (on the dev clips the previous value beats linear extrapolation: the
tracker's frame-to-frame noise is not smooth). A residual is binarised as zero
flag, sign and Exp-Golomb magnitude; each binary decision has an adaptive model
chosen by the local activity (this parameter's last residual, the previous
parameter's residual in this frame), so still mouths cost a fraction of a bit and
speech costs what it must. All models live in one :class:`GroupState` that is
reset at every keyframe: a lost packet can never corrupt decoding past the next
keyframe.

What a second of data cannot learn on its own is built in: the zero flag and
the prefix also depend on the value's axis (the coding basis puts the largest
motion first), the first bit below a magnitude's leading one has a model, and
every model starts from trained counts (``protocol/priors.py``) instead of
from nothing, so the reset at each keyframe costs little. After each frame of a
delta packet comes whether another follows: the packet then ends itself, and
the flag costs almost nothing because a packet usually holds as many frames as
the one before.
"""

from collections.abc import Callable

from facedeform.common.errors import BitstreamError
from facedeform.protocol.arith import AdaptiveBit, Decoder, Encoder

MAX_EXP = 24  # magnitudes below 2**25 steps; a longer prefix can only be damage
_PREFIX_MODELS = 8
_MANTISSA_MODELS = 8
_CLASSES = 4
_AXIS_GROUPS = (0, 1, 2, 3, 4, 4, 4, 4, 5)  # by axis, the last for axes 8 and up
#: Makes the bit model named by a key such as ("delta", "prefix", axis group, class, position).
NewBit = Callable[[tuple], AdaptiveBit]


def _activity_class(last: int, neighbour: int) -> int:
    a = 2 * abs(last) + abs(neighbour)
    return 0 if a == 0 else 1 if a <= 2 else 2 if a <= 8 else 3


class _IntModels:
    """Models of one kind of value ("key": keyframe values, "delta": residuals).

    Zero flag and prefix per axis group and activity class, sign per previous
    sign, the first mantissa bit per exponent.
    """

    def __init__(self, kind: str, new_bit: NewBit) -> None:
        groups = max(_AXIS_GROUPS) + 1
        self.zero = [[new_bit((kind, "zero", g, c)) for c in range(_CLASSES)] for g in range(groups)]
        self.sign = [new_bit((kind, "sign", s)) for s in range(3)]
        self.prefix = [[[new_bit((kind, "prefix", g, c, i)) for i in range(_PREFIX_MODELS)]
                        for c in range(_CLASSES)] for g in range(groups)]
        self.mantissa = [new_bit((kind, "mantissa", e)) for e in range(_MANTISSA_MODELS)]

    @staticmethod
    def group(axis: int) -> int:
        return _AXIS_GROUPS[min(axis, len(_AXIS_GROUPS) - 1)]

    def first_mantissa(self, exp: int) -> AdaptiveBit:
        return self.mantissa[min(exp, _MANTISSA_MODELS) - 1]


def _encode_int(enc: Encoder, value: int, m: _IntModels, axis: int, cls: int, last: int) -> None:
    g = m.group(axis)
    enc.bit(value != 0, m.zero[g][cls])
    if value == 0:
        return
    enc.bit(value < 0, m.sign[(last > 0) - (last < 0) + 1])
    mag = abs(value)
    exp = mag.bit_length() - 1
    if exp > MAX_EXP:
        raise BitstreamError(f"value {value} out of range for the stream's steps")
    prefix = m.prefix[g][cls]
    for i in range(exp):
        enc.bit(1, prefix[min(i, _PREFIX_MODELS - 1)])
    if exp < MAX_EXP:
        enc.bit(0, prefix[min(exp, _PREFIX_MODELS - 1)])
    for i in range(exp - 1, -1, -1):
        enc.bit((mag >> i) & 1, m.first_mantissa(exp) if i == exp - 1 else None)


def _decode_int(dec: Decoder, m: _IntModels, axis: int, cls: int, last: int) -> int:
    g = m.group(axis)
    if not dec.bit(m.zero[g][cls]):
        return 0
    negative = dec.bit(m.sign[(last > 0) - (last < 0) + 1])
    prefix = m.prefix[g][cls]
    exp = 0
    while exp < MAX_EXP and dec.bit(prefix[min(exp, _PREFIX_MODELS - 1)]):
        exp += 1
    mag = 1
    for i in range(exp - 1, -1, -1):
        mag = (mag << 1) | dec.bit(m.first_mantissa(exp) if i == exp - 1 else None)
    return -mag if negative else mag


class GroupState:
    """What both ends hold between keyframes: last values, last residuals and all models.

    ``k`` parameters; ``static`` adds a per-frame "same as before" flag;
    ``new_bit`` makes each model (``protocol.priors.models_for``: from trained counts).
    """

    def __init__(self, k: int, static: bool, new_bit: NewBit) -> None:
        self.k, self.static = k, static
        self.active = 0  # frames of the current packet that are not static
        self._last_active = 0  # the same for the packet before
        self.values: list[int] = [0] * k
        self.face = True
        self._residuals = [0] * k
        self._delta = _IntModels("delta", new_bit)  # shared across parameters: one second is too short to learn each
        self._absolute = _IntModels("key", new_bit)  # keyframe values: one keyframe per group
        self._face = [new_bit(("frame", "face", f)) for f in range(2)]
        self._static = new_bit(("frame", "static"))
        self._more = [new_bit(("frame", "more", c)) for c in range(2)]  # by: as many frames as the last packet yet

    def encode_key(self, enc: Encoder, values: list[int], face: bool) -> None:
        enc.bit(face, self._face[1])
        for j, v in enumerate(values):
            _encode_int(enc, v, self._absolute, j, 0, 0)
        self.values, self.face = list(values), face
        self.active += 1

    def decode_key(self, dec: Decoder) -> tuple[list[int], bool]:
        self.face = bool(dec.bit(self._face[1]))
        self.values = [_decode_int(dec, self._absolute, j, 0, 0) for j in range(self.k)]
        self.active += 1
        return list(self.values), self.face

    def is_static(self, values: list[int], face: bool) -> bool:
        return self.static and face == self.face and values == self.values

    def encode_delta(self, enc: Encoder, values: list[int], face: bool) -> None:
        if self.static:
            static = self.is_static(values, face)
            enc.bit(static, self._static)
            if static:
                self._residuals = [0] * self.k
                return
        enc.bit(face, self._face[self.face])
        self.face = face
        neighbour = 0
        for j, v in enumerate(values):
            r = v - self.values[j]
            last = self._residuals[j]
            _encode_int(enc, r, self._delta, j, _activity_class(last, neighbour), last)
            self._residuals[j] = neighbour = r
        self.values = list(values)
        self.active += 1

    def decode_delta(self, dec: Decoder) -> tuple[list[int], bool]:
        if self.static and dec.bit(self._static):
            self._residuals = [0] * self.k
            return list(self.values), self.face
        self.face = bool(dec.bit(self._face[self.face]))
        neighbour = 0
        for j in range(self.k):
            last = self._residuals[j]
            r = _decode_int(dec, self._delta, j, _activity_class(last, neighbour), last)
            self.values[j] += r
            self._residuals[j] = neighbour = r
        self.active += 1
        return list(self.values), self.face

    def encode_more(self, enc: Encoder, more: bool) -> None:
        """Whether another frame follows in this delta packet."""
        enc.bit(more, self._more[self.active >= self._last_active])

    def decode_more(self, dec: Decoder) -> bool:
        return bool(dec.bit(self._more[self.active >= self._last_active]))

    def state(self) -> tuple:
        """What decoding changes apart from the models (which a decoder's journal records)."""
        return list(self.values), list(self._residuals), self.face, self.active, self._last_active

    def restore(self, state: tuple, journal: list) -> None:
        """Undoes a trial decode: ``state`` from before it, ``journal`` its decoder's."""
        for model, n0, n1 in reversed(journal):
            model.n0, model.n1 = n0, n1
        self.values, self._residuals, self.face, self.active, self._last_active = state

    def end_packet(self) -> None:
        self._last_active, self.active = self.active, 0
