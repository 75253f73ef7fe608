"""Progress on stderr for long work, shown only when stderr is a terminal: a bar for file work, and
a line for a step that turns out slow (the renderer's first compilation after an install)."""

import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

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


#: Seconds a step may take before :func:`slow_step` says what is happening.
SLOW = 1.0


@contextmanager
def slow_step(prog: str, what: str, quiet: bool, stream=None) -> Iterator[None]:
    """Says ``prog: what...`` on ``stream`` (default stderr, a terminal only, not ``quiet``) if the
    step inside takes more than SLOW seconds, and how long it took once it is done."""
    stream = stream or sys.stderr
    started = time.monotonic()
    said = threading.Event()

    def say() -> None:
        stream.write(f"{prog}: {what}...\n")
        stream.flush()
        said.set()

    timer = threading.Timer(SLOW, say) if not quiet and stream.isatty() else None
    if timer is not None:
        timer.daemon = True
        timer.start()
    try:
        yield
    finally:
        if timer is not None:
            timer.cancel()
            if said.is_set():
                stream.write(f"{prog}: ready after {time.monotonic() - started:.0f} s\n")
                stream.flush()
