"""A progress line on stderr for file work, drawn only when stderr is a terminal."""

import sys
import time

INTERVAL = 0.2  # seconds between redraws


class Progress:
    """``update(done, total, note)`` redraws at most every INTERVAL; ``close()`` clears the line."""

    def __init__(self, prog: str, stream=None) -> None:
        self._prog, self._stream = prog, stream or sys.stderr
        self._last = 0.0
        self._drawn = False

    def update(self, done: int, total: int, note: str = "") -> None:
        now = time.monotonic()
        if now - self._last < INTERVAL or total <= 0:
            return
        self._last = now
        share = min(done / total, 1.0)
        bar = "#" * round(30 * share)
        self._stream.write(f"\r{self._prog}: [{bar:<30}] {100 * share:3.0f}% {note}\x1b[K")
        self._stream.flush()
        self._drawn = True

    def close(self) -> None:
        if self._drawn:
            self._stream.write("\r\x1b[K")
            self._stream.flush()


def progress_for(prog: str, quiet: bool, stream=None) -> Progress | None:
    """A Progress when ``stream`` (default stderr) is a terminal and the user did not ask for quiet."""
    stream = stream or sys.stderr
    return Progress(prog, stream) if not quiet and stream.isatty() else None
