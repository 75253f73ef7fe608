"""Progress lines: drawn on a terminal only, at most every INTERVAL, cleared at the end."""

import io
import threading

from facedeform.common.progress import Progress, progress_for


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_only_on_a_terminal_and_not_when_quiet():
    assert progress_for("fd-send", False, io.StringIO()) is None
    assert progress_for("fd-send", True, Terminal()) is None
    assert isinstance(progress_for("fd-send", False, Terminal()), Progress)


def test_progress_draws_a_bar_and_clears_it():
    out = Terminal()
    bar = Progress("fd-send", out)
    bar.update(30, 60, "30 frames")
    bar.update(31, 60, "31 frames")  # within INTERVAL: not redrawn
    text = out.getvalue()
    assert text.count("\r") == 1 and " 50% 30 frames" in text and "#" * 15 in text
    bar.close()
    assert out.getvalue().endswith("\r\x1b[K")



class WatchedTerminal(Terminal):
    """A terminal that tells when something is written to it."""

    def __init__(self) -> None:
        super().__init__()
        self.written = threading.Event()

    def write(self, text: str) -> int:
        count = super().write(text)
        self.written.set()
        return count


def test_a_slow_step_says_what_is_happening_and_when_it_is_done(monkeypatch):
    from facedeform.common import progress

    monkeypatch.setattr(progress, "SLOW", 0.01)
    terminal = WatchedTerminal()
    with progress.slow_step("fd-recv", "compiling", quiet=False, stream=terminal):
        assert terminal.written.wait(30)  # said while the step still runs
        assert terminal.getvalue() == "fd-recv: compiling...\n"
    assert terminal.getvalue().splitlines()[-1].startswith("fd-recv: ready after")


def test_a_quick_or_quiet_step_says_nothing():
    from facedeform.common import progress

    for quiet in (False, True):
        terminal = WatchedTerminal()
        with progress.slow_step("fd-recv", "compiling", quiet=quiet, stream=terminal):
            pass
        assert terminal.getvalue() == ""
