"""The in-band face model put together from its chunks, in whatever order they come.

A byte stream brings the chunks in order, once. Over UDP a paced face goes round and round
(sender/face_pacing.py) so that a receiver that lost a chunk, or joined the call late, takes it on
a later round; the chunks then come from anywhere in the model, some twice. What is held is kept as
separate pieces, each byte stored once, so memory grows with what arrived, never with the size a
header claims; a stream that would scatter the model into more than MAX_PIECES pieces is damaged.
"""

from bisect import bisect_right

#: Separate pieces of a model held at once. A round of a paced face leaves one gap per chunk lost;
#: a stream that needs more is not one the sender made.
MAX_PIECES = 1024


class ModelParts:
    """The ``size`` bytes of a face model."""

    def __init__(self, size: int) -> None:
        self.size = size
        self._starts: list[int] = []  # sorted starts of the pieces held, which neither overlap nor touch
        self._pieces: list[bytearray] = []
        self.held = 0  # bytes held

    @property
    def whole(self) -> bool:
        return self.held == self.size

    @property
    def missing(self) -> int:
        """The first byte not held (``size`` once whole): what a receiver reports back."""
        return len(self._pieces[0]) if self._starts and self._starts[0] == 0 else 0

    def add(self, offset: int, chunk: bytes) -> bool | None:
        """Takes ``chunk`` at ``offset``; False if it brought nothing new, None if it cannot be part of the
        model (out of its bounds, or it would leave more than MAX_PIECES pieces)."""
        end = offset + len(chunk)
        if not chunk or offset < 0 or end > self.size:
            return None
        i = bisect_right(self._starts, offset) - 1  # the piece at or before offset
        if i >= 0 and self._starts[i] + len(self._pieces[i]) >= end:
            return False
        if i >= 0 and self._starts[i] + len(self._pieces[i]) >= offset:  # joins the piece before
            start, piece = self._starts[i], self._pieces[i]
        else:
            i += 1
            if len(self._starts) >= MAX_PIECES:
                return None
            self._starts.insert(i, offset)
            self._pieces.insert(i, bytearray())
            start, piece = offset, self._pieces[i]
        had = len(piece)
        piece += chunk[start + had - offset:]
        while i + 1 < len(self._starts) and self._starts[i + 1] <= start + len(piece):  # the pieces it reaches
            later_start, later = self._starts.pop(i + 1), self._pieces.pop(i + 1)
            self.held -= len(later)
            piece += later[start + len(piece) - later_start:]
        self.held += len(piece) - had
        return True

    def bytes(self, end: int | None = None) -> bytes:
        """The model's first ``end`` bytes (all of it by default); they must be held."""
        end = self.size if end is None else end
        if self.missing < end:
            raise ValueError(f"bytes up to {end} are not all held")
        return bytes(self._pieces[0][:end]) if end else b""
