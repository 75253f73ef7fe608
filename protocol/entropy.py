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
"""

from codec.errors import BitstreamError
from protocol.arith import AdaptiveBit, Decoder, Encoder

MAX_EXP = 24  # magnitudes below 2**25 steps; a longer prefix can only be damage
_PREFIX_MODELS = 8
_CLASSES = 4


def _activity_class(last: int, neighbour: int) -> int:
    a = 2 * abs(last) + abs(neighbour)
    return 0 if a == 0 else 1 if a <= 2 else 2 if a <= 8 else 3


class _IntModels:
    """Models of residuals: zero flag and prefix per activity class, sign per previous sign."""

    def __init__(self) -> None:
        self.zero = [AdaptiveBit() for _ in range(_CLASSES)]
        self.sign = [AdaptiveBit() for _ in range(3)]
        self.prefix = [[AdaptiveBit() for _ in range(_PREFIX_MODELS)] for _ in range(_CLASSES)]


def _encode_int(enc: Encoder, value: int, m: _IntModels, cls: int, last: int) -> None:
    enc.bit(value != 0, m.zero[cls])
    if value == 0:
        return
    enc.bit(value < 0, m.sign[(last > 0) - (last < 0) + 1])
    mag = abs(value)
    exp = mag.bit_length() - 1
    if exp > MAX_EXP:
        raise BitstreamError(f"value {value} out of range for the stream's steps")
    prefix = m.prefix[cls]
    for i in range(exp):
        enc.bit(1, prefix[min(i, _PREFIX_MODELS - 1)])
    if exp < MAX_EXP:
        enc.bit(0, prefix[min(exp, _PREFIX_MODELS - 1)])
    for i in range(exp - 1, -1, -1):
        enc.bit((mag >> i) & 1)


def _decode_int(dec: Decoder, m: _IntModels, cls: int, last: int) -> int:
    if not dec.bit(m.zero[cls]):
        return 0
    negative = dec.bit(m.sign[(last > 0) - (last < 0) + 1])
    prefix = m.prefix[cls]
    exp = 0
    while exp < MAX_EXP and dec.bit(prefix[min(exp, _PREFIX_MODELS - 1)]):
        exp += 1
    mag = 1
    for _ in range(exp):
        mag = (mag << 1) | dec.bit()
    return -mag if negative else mag


class GroupState:
    """What both ends hold between keyframes: last values, last residuals and all models.

    ``k`` parameters; ``static`` adds a per-frame "same as before" flag.
    """

    def __init__(self, k: int, static: bool) -> None:
        self.k, self.static = k, static
        self.values: list[int] = [0] * k
        self.face = True
        self._residuals = [0] * k
        self._delta = _IntModels()  # shared: learns within one second, per-parameter models do not
        self._absolute = _IntModels()  # keyframe values, shared: there is one keyframe per group
        self._face = [AdaptiveBit(), AdaptiveBit()]
        self._static = AdaptiveBit()

    def encode_key(self, enc: Encoder, values: list[int], face: bool) -> None:
        enc.bit(face, self._face[1])
        for v in values:
            _encode_int(enc, v, self._absolute, 0, 0)
        self.values, self.face = list(values), face

    def decode_key(self, dec: Decoder) -> tuple[list[int], bool]:
        self.face = bool(dec.bit(self._face[1]))
        self.values = [_decode_int(dec, self._absolute, 0, 0) for _ in range(self.k)]
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
            _encode_int(enc, r, self._delta, _activity_class(last, neighbour), last)
            self._residuals[j] = neighbour = r
        self.values = list(values)

    def decode_delta(self, dec: Decoder) -> tuple[list[int], bool]:
        if self.static and dec.bit(self._static):
            self._residuals = [0] * self.k
            return list(self.values), self.face
        self.face = bool(dec.bit(self._face[self.face]))
        neighbour = 0
        for j in range(self.k):
            last = self._residuals[j]
            r = _decode_int(dec, self._delta, _activity_class(last, neighbour), last)
            self.values[j] += r
            self._residuals[j] = neighbour = r
        return list(self.values), self.face
