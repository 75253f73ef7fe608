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

A long run of bits under one model (the picture layer's block choices, about
2,000 a frame at 1920x1080) has compiled twins, :func:`encode_run` and
:func:`decode_run`, that keep the interval in a 32-bit window with the bytes
above it written out (a carry ripples into them) and give the same bytes and
bits as the coder above: in Python a 1080p frame's choices took 1.4 ms to code
and 1.7 to decode.
"""

import numpy as np
from numba import njit

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


def encode_run(bits: np.ndarray, model: AdaptiveBit) -> bytes:
    """The bytes of :class:`Encoder` coding each of ``bits`` (0 or 1) with ``model`` (updated as
    it would be), then :meth:`Encoder.end`."""
    bits = np.ascontiguousarray(bits, dtype=np.uint8)
    out = np.zeros(2 * bits.size + 8, np.uint8)  # a bit keeps at least 2**-16 of the range: 2 bytes out at most
    written, low, span, shift, n0, n1 = _encode(bits, model.n0, model.n1, out)
    model.n0, model.n1 = int(n0), int(n1)
    start = int.from_bytes(out[:written].tobytes(), "big") << 32 | low
    return _self_delimiting_end(start, start + span, shift)


def decode_run(data: bytes, count: int, model: AdaptiveBit) -> tuple[np.ndarray, int] | None:
    """(``count`` bits as :class:`Decoder` reads them with ``model``, updated as it would be; the
    bytes the code took, :meth:`Decoder.end`) from the start of ``data``; None if it ends too soon.
    The compiled run reads past the end of ``data`` as zeros; where the bytes the code took do not
    settle every bit by themselves (a code cut short, or not one), the exact decoder decides."""
    n0, n1 = model.n0, model.n1
    bits = np.empty(count, np.uint8)
    read, code, span, shift, after0, after1 = _decode(np.frombuffer(data, np.uint8), count, n0, n1, bits)
    low = (int.from_bytes(data[:read], "big") << 8 * (read - min(read, len(data)))) - code
    end = _self_delimiting_end(low, low + span, shift)
    at = int.from_bytes(data[:len(end)], "big") << (shift - 8 * len(end))
    if len(end) <= len(data) and low <= at and at + (1 << (shift - 8 * len(end))) <= low + span:
        model.n0, model.n1 = int(after0), int(after1)
        return bits, len(end)
    decoder = Decoder(data)
    try:
        exact = np.array([decoder.bit(model) for _ in range(count)], dtype=np.uint8)
        return exact, len(decoder.end())
    except Incomplete:
        return None


#: :func:`encode_integers`' magnitude classes: |v| - 1 has 0 to CLASSES - 1 binary digits.
CLASSES = 17
LARGEST = 1 << (CLASSES - 1)  # the largest magnitude coded
_ZERO, _SIGN, _CLASS = 0, 1, 2  # a group's models: whether 0, the sign, the class in unary, then each digit
_MODELS = _CLASS + 2 * CLASSES - 1


def encode_integers(values: np.ndarray, groups: np.ndarray, count: int) -> bytes:
    """The code of integers ``values`` (|v| <= LARGEST), each in its group of ``groups`` (0 to
    ``count`` - 1), then :meth:`Encoder.end`: per integer whether it is 0, its sign, the number of
    binary digits of its magnitude less one in unary (an Elias-gamma code), then those digits below
    the leading one, each bit under its group's adaptive model for that place (a face's preview
    mesh, in steps 8 times the file's, learns that its last three digits are 0).

    Why not LZMA for a face file's mesh and basis: they are small integers, near independent once
    predicted from their neighbours, and a byte-wise dictionary coder took a third more bytes for
    them than this code does (docs/face_file.md)."""
    values = np.asarray(values, np.int64)
    if values.size and np.abs(values).max() > LARGEST:
        raise ValueError(f"integers to code lie within +-{LARGEST}")
    n0 = np.zeros((count, _MODELS), np.int64)
    out = np.zeros(2 * (2 + CLASSES + 15) * values.size + 8, np.uint8)  # bits of 2 bytes out at most each
    written, low, span, shift = _encode_integers(values, np.asarray(groups, np.int64), n0, n0.copy(), out)
    start = int.from_bytes(out[:written].tobytes(), "big") << 32 | low
    return _self_delimiting_end(start, start + span, shift)


def decode_integers(data: bytes, groups: np.ndarray, count: int) -> np.ndarray:
    """The integers of :func:`encode_integers` (one per entry of ``groups``) from ``data``, read as
    zeros past its end: bytes that are not such a code give integers all the same, within +-LARGEST,
    in time bounded by their number."""
    n0 = np.zeros((count, _MODELS), np.int64)
    groups = np.asarray(groups, np.int64)
    values = np.empty(groups.size, np.int64)
    _decode_integers(np.frombuffer(data, np.uint8), groups, n0, n0.copy(), values)
    return values


@njit(cache=True)
def _counted(bit, n0, n1):  # pragma: no cover - compiled
    """AdaptiveBit.update's counts."""
    if bit:
        n1 += 1
    else:
        n0 += 1
    if n0 + n1 > _COUNT_LIMIT:
        n0, n1 = (n0 + 1) >> 1, (n1 + 1) >> 1
    return n0, n1


@njit(cache=True)
def _p0(n0, n1):  # pragma: no cover - compiled
    """AdaptiveBit.p0 of counts n0, n1."""
    return ((2 * n0 + 1) << PROB_BITS) // (2 * (n0 + n1) + 2)


@njit(cache=True)
def _primed(data):  # pragma: no cover - compiled
    """A decoder's start on ``data``, read as zeros past its end: (code, range, shift, bytes read)."""
    code = np.int64(0)
    for read in range(4):
        code = code << 8 | (data[read] if read < data.size else 0)
    return code, np.int64(1) << 32, 32, 4


@njit(cache=True)
def _encode(bits, n0, n1, out):  # pragma: no cover - compiled
    """Encoder.bit over ``bits`` from an empty Encoder: the interval's start is the bytes written to
    ``out`` then ``low`` (under 2**32), as (bytes written, low, range, shift, n0, n1)."""
    low, span, shift, written = np.int64(0), np.int64(1) << 32, 32, 0
    for bit in bits:
        low, span, shift, written = _put(bit, _p0(n0, n1), low, span, shift, written, out)
        n0, n1 = _counted(bit, n0, n1)
    return written, low, span, shift, n0, n1


@njit(cache=True)
def _decode(data, count, n0, n1, bits):  # pragma: no cover - compiled
    """Decoder.bit ``count`` times into ``bits``, the data read as zeros past its end: (bytes read,
    the read bytes' value less the interval's start, range, shift, n0, n1)."""
    code, span, shift, read = _primed(data)
    for k in range(count):
        bit, code, span, shift, read = _get(_p0(n0, n1), code, span, shift, read, data)
        bits[k] = bit
        n0, n1 = _counted(bit, n0, n1)
    return read, code, span, shift, n0, n1


@njit(cache=True)
def _put(bit, p0, low, span, shift, written, out):  # pragma: no cover - compiled
    """One bit at P(0) = p0 into the interval whose start is the bytes written to ``out`` then ``low``:
    (low, span, shift, written) after it."""
    split = (span * p0) >> PROB_BITS
    if bit:
        low += split
        span -= split
    else:
        span = split
    if low >> 32:  # a carry into the bytes written: the interval never passes the code's end
        low -= np.int64(1) << 32
        i = written - 1
        while out[i] == 255:
            out[i] = 0
            i -= 1
        out[i] += 1
    while span < _MIN_RANGE:
        out[written] = low >> 24
        written += 1
        low = (low & 0xFFFFFF) << 8
        span <<= 8
        shift += 8
    return low, span, shift, written


@njit(cache=True)
def _put_modelled(bit, n0, n1, g, m, low, span, shift, written, out):  # pragma: no cover - compiled
    """_put under model m of group g (counts n0, n1, updated)."""
    state = _put(bit, _p0(n0[g, m], n1[g, m]), low, span, shift, written, out)
    n0[g, m], n1[g, m] = _counted(bit, n0[g, m], n1[g, m])
    return state


@njit(cache=True)
def _encode_integers(values, groups, n0, n1, out):  # pragma: no cover - compiled
    """encode_integers' bits from an empty Encoder, as _encode: (bytes written, low, range, shift)."""
    low, span, shift, written = np.int64(0), np.int64(1) << 32, 32, 0
    for k in range(values.size):
        v, g = values[k], groups[k]
        low, span, shift, written = _put_modelled(v != 0, n0, n1, g, _ZERO, low, span, shift, written, out)
        if v == 0:
            continue
        low, span, shift, written = _put_modelled(v < 0, n0, n1, g, _SIGN, low, span, shift, written, out)
        rest = abs(v) - 1
        digits = 0
        while rest >> digits:
            digits += 1
        for i in range(digits):
            low, span, shift, written = _put_modelled(1, n0, n1, g, _CLASS + i, low, span, shift, written, out)
        if digits < CLASSES - 1:
            low, span, shift, written = _put_modelled(0, n0, n1, g, _CLASS + digits, low, span, shift, written, out)
        for i in range(digits - 2, -1, -1):
            low, span, shift, written = _put_modelled((rest >> i) & 1, n0, n1, g, _CLASS + CLASSES + i, low, span,
                                                      shift, written, out)
    return written, low, span, shift


@njit(cache=True)
def _get(p0, code, span, shift, read, data):  # pragma: no cover - compiled
    """One bit at P(0) = p0 from ``data``, read as zeros past its end, ``code`` its read bytes' value less
    the interval's start: (bit, code, span, shift, read) after it."""
    split = (span * p0) >> PROB_BITS
    bit = code >= split
    if bit:
        code -= split
        span -= split
    else:
        span = split
    while span < _MIN_RANGE:
        code = code << 8 | (data[read] if read < data.size else 0)
        read += 1
        span <<= 8
        shift += 8
    return bit, code, span, shift, read


@njit(cache=True)
def _get_modelled(n0, n1, g, m, code, span, shift, read, data):  # pragma: no cover - compiled
    """_get under model m of group g (counts n0, n1, updated)."""
    bit, code, span, shift, read = _get(_p0(n0[g, m], n1[g, m]), code, span, shift, read, data)
    n0[g, m], n1[g, m] = _counted(bit, n0[g, m], n1[g, m])
    return bit, code, span, shift, read


@njit(cache=True)
def _decode_integers(data, groups, n0, n1, values):  # pragma: no cover - compiled
    """_encode_integers' integers into ``values``, the data read as zeros past its end."""
    code, span, shift, read = _primed(data)
    for k in range(values.size):
        g = groups[k]
        nonzero, code, span, shift, read = _get_modelled(n0, n1, g, _ZERO, code, span, shift, read, data)
        if not nonzero:
            values[k] = 0
            continue
        negative, code, span, shift, read = _get_modelled(n0, n1, g, _SIGN, code, span, shift, read, data)
        digits = 0
        while digits < CLASSES - 1:
            more, code, span, shift, read = _get_modelled(n0, n1, g, _CLASS + digits, code, span, shift, read, data)
            if not more:
                break
            digits += 1
        rest = np.int64(1) << (digits - 1) if digits else np.int64(0)
        for i in range(digits - 2, -1, -1):
            bit, code, span, shift, read = _get_modelled(n0, n1, g, _CLASS + CLASSES + i, code, span, shift, read, data)
            rest |= np.int64(bit) << i
        values[k] = -(rest + 1) if negative else rest + 1
    return read
