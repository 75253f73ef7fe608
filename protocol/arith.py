"""Binary arithmetic coding with exact integers and adaptive bit models.

Why not a word-based library coder (constriction emits 32-bit words): a delta
packet carries 20-100 bits, so rounding each packet up to whole words would cost
more than the data. Python integers have no width, so this coder keeps the
interval exactly (no carry handling), ends on the shortest bit string inside the
final interval and drops trailing zero bytes, which the decoder reads back as
zeros. Everything is integer arithmetic: both ends compute identical
probabilities on any machine.
"""

PROB_BITS = 16
_ONE = 1 << PROB_BITS
_HALF = _ONE >> 1
_MIN_RANGE = 1 << 24  # renormalise below this: split points keep >= 8 bits of precision
_COUNT_LIMIT = 60  # halve counts beyond this so the model follows drift


class AdaptiveBit:
    """Probability of a 0 from counts (Krichevsky-Trofimov): learns in a handful of symbols.

    ``n0``, ``n1``: starting counts (trained ones spare the first symbols' learning).
    """

    __slots__ = ("n0", "n1")

    def __init__(self, n0: int = 0, n1: int = 0) -> None:
        self.n0, self.n1 = n0, n1

    def p0(self) -> int:
        """P(bit = 0) in units of 2**-16, always inside (0, 2**16)."""
        return ((2 * self.n0 + 1) << PROB_BITS) // (2 * (self.n0 + self.n1) + 2)

    def update(self, bit: int) -> None:
        if bit:
            self.n1 += 1
        else:
            self.n0 += 1
        if self.n0 + self.n1 > _COUNT_LIMIT:
            self.n0, self.n1 = (self.n0 + 1) >> 1, (self.n1 + 1) >> 1


class Encoder:
    """Codes bits into the interval [low, low + range) * 2**-shift."""

    def __init__(self) -> None:
        self._low, self._range, self._shift = 0, 1 << 32, 32

    def bit(self, bit: int, model: AdaptiveBit | None = None) -> None:
        """Codes ``bit`` with ``model`` (then updates it), or at probability 1/2 without one."""
        p0 = _HALF if model is None else model.p0()
        split = (self._range * p0) >> PROB_BITS
        if bit:
            self._low += split
            self._range -= split
        else:
            self._range = split
        if model is not None:
            model.update(bit)
        while self._range < _MIN_RANGE:
            self._low <<= 8
            self._range <<= 8
            self._shift += 8

    def finish(self) -> bytes:
        """The shortest byte string whose value lies inside the final interval."""
        low, high = self._low, self._low + self._range
        for drop in range(self._shift, -1, -1):  # most trailing zero bits first
            value = -(-low >> drop) << drop
            if value < high:
                break
        nbytes = (self._shift - drop + 7) // 8
        data = (value >> (self._shift - 8 * nbytes) if 8 * nbytes <= self._shift
                else value << (8 * nbytes - self._shift)).to_bytes(nbytes, "big")
        return data.rstrip(b"\0")


class Decoder:
    """Reads the bits of :class:`Encoder`; bytes past the end read as zeros."""

    def __init__(self, data: bytes) -> None:
        self._value, self._bits = int.from_bytes(data, "big"), 8 * len(data)
        self._low, self._range, self._shift = 0, 1 << 32, 32

    def bit(self, model: AdaptiveBit | None = None) -> int:
        p0 = _HALF if model is None else model.p0()
        split = (self._range * p0) >> PROB_BITS
        bit = int((self._value << self._shift) >= (self._low + split) << self._bits)
        if bit:
            self._low += split
            self._range -= split
        else:
            self._range = split
        if model is not None:
            model.update(bit)
        while self._range < _MIN_RANGE:
            self._low <<= 8
            self._range <<= 8
            self._shift += 8
        return bit
