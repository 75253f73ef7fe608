"""User mistakes across the tools: each is one line on stderr and a non-zero exit, caught before the work."""

import sys

import pytest

from tests.test_cli import ROOT, assert_one_line_error, run

ANIMATE = [sys.executable, "-m", "receiver.animate"]
SCRIPT = str(ROOT / "samples" / "animation.txt")


@pytest.mark.parametrize("args, message", [
    ([SCRIPT, "-o", "/nonexistent/a.mp4"], "does not exist"),
    ([SCRIPT, "-o", SCRIPT], "is the input"),
    ([SCRIPT, "--fps", "nan"], "out of range"),
    ([SCRIPT, "--fps", "0"], "out of range"),
])
def test_animate_mistakes(args, message):
    result = run(ANIMATE + args)
    assert_one_line_error(result, "fd-animate")
    assert message in result.stderr.decode()


def test_animate_refuses_a_script_of_absurd_length(tmp_path):
    script = tmp_path / "long.txt"
    script.write_text("0 neutral\n10000000 smile\n")
    result = run(ANIMATE + [str(script), "-o", str(tmp_path / "a.mp4")])
    assert_one_line_error(result, "fd-animate")
    assert "lasts" in result.stderr.decode() and not (tmp_path / "a.mp4").exists()
