"""Progress lines: drawn on a terminal only, at most every INTERVAL, cleared at the end."""

import io

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
