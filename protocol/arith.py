"""Binary arithmetic coding with exact integers and adaptive bit models.

Why not a word-based library coder (constriction emits 32-bit words): a delta
packet carries 20-100 bits, so rounding each packet up to whole words would cost
more than the data. Python integers have no width, so this coder keeps the
interval exactly (no carry handling). It ends itself (:meth:`Encoder.end`): the
fewest bytes such that whatever follows them the value stays inside the final
interval. A decoder holding the same interval knows that length itself
(:meth:`Decoder.end`), so the code needs no length field, and the bytes that
follow (the next packet) cannot change what it decodes.

Everything is integer arithmetic: both ends compute identical probabilities on
any machine.
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


class Incomplete(Exception):
    """An open-ended code needs bytes that have not arrived."""


def _self_delimiting_end(low: int, high: int, shift: int) -> bytes:
    """The fewest bytes ``s`` with [s, s + 1) * 2**-8len inside [low, high) * 2**-shift."""
    for n in range(shift // 8 + 1):
        d = shift - 8 * n
        s = -(-low >> d)
        if (s + 1) << d <= high:
            return s.to_bytes(n, "big")
    raise AssertionError("an interval of at least one unit always holds a whole byte string")


class Encoder:
    """Codes bits into the interval [low, low + range) * 2**-shift.

    ``first_byte_below``: the code starts inside [0, first_byte_below / 256), so
    its first byte is always below that value (a sync byte can then never start
    it), for log2(256 / first_byte_below) bits. :attr:`trace` holds every bit
    coded, oldest first, behind a leading 1.
    """

    def __init__(self, first_byte_below: int = 256) -> None:
        self._low, self._range, self._shift = 0, first_byte_below << 24, 32
        self.trace = 1

    def bit(self, bit: int, model: AdaptiveBit | None = None) -> None:
        """Codes ``bit`` with ``model`` (then updates it), or at probability 1/2 without one."""
        p0 = _HALF if model is None else model.p0()
        split = (self._range * p0) >> PROB_BITS
        if bit:
            self._low += split
            self._range -= split
        else:
            self._range = split
        self.trace = self.trace << 1 | bit
        if model is not None:
            model.update(bit)
        while self._range < _MIN_RANGE:
            self._low <<= 8
            self._range <<= 8
            self._shift += 8

    def end(self) -> bytes:
        """The self-delimiting end: see the module docstring."""
        return _self_delimiting_end(self._low, self._low + self._range, self._shift)


class Decoder:
    """Reads the bits of :class:`Encoder` (the same ``first_byte_below``).

    ``data`` may be followed by bytes not yet known: a bit they would decide
    raises :class:`Incomplete`. Bytes are read only as far as the bits need.
    """

    def __init__(self, data: bytes, first_byte_below: int = 256) -> None:
        self._data = data
        self._value = self._n = 0  # the first _n bytes of data, read so far
        self._low, self._range, self._shift = 0, first_byte_below << 24, 32
        self.trace = 1
        self.journal: list[tuple[AdaptiveBit, int, int]] | None = None

    def bit(self, model: AdaptiveBit | None = None) -> int:
        p0 = _HALF if model is None else model.p0()
        split = (self._range * p0) >> PROB_BITS
        threshold = self._low + split
        while True:  # the unread bytes put the value in [value, value + 1) * 2**-8n
            bits = 8 * self._n
            if (self._value << self._shift) >= threshold << bits:
                bit = 1
                break
            if (self._value + 1) << self._shift <= threshold << bits:
                bit = 0
                break
            if self._n < len(self._data):
                more = min(len(self._data), self._n + 4)
                self._value = self._value << 8 * (more - self._n) | int.from_bytes(self._data[self._n:more], "big")
                self._n = more
            else:
                raise Incomplete
        if bit:
            self._low += split
            self._range -= split
        else:
            self._range = split
        self.trace = self.trace << 1 | bit
        if model is not None:
            if self.journal is not None:
                self.journal.append((model, model.n0, model.n1))
            model.update(bit)
        while self._range < _MIN_RANGE:
            self._low <<= 8
            self._range <<= 8
            self._shift += 8
        return bit

    def end(self) -> bytes:
        """What :meth:`Encoder.end` returned for the bits decoded so far: the code's own bytes."""
        return _self_delimiting_end(self._low, self._low + self._range, self._shift)
