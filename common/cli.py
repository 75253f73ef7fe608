"""What every command-line tool of the project shares: one-line errors and exit codes."""

import argparse
import sys
from collections.abc import Callable


class ArgumentParser(argparse.ArgumentParser):
    """argparse, but a wrong argument is one line on stderr (exit 2), as every other user mistake."""

    def __init__(self, **kwargs) -> None:
        kwargs.setdefault("formatter_class", argparse.RawDescriptionHelpFormatter)
        super().__init__(**kwargs)

    def error(self, message: str):
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def parse_size(text: str) -> tuple[int, int]:
    """An argparse type for an output size: ``512`` or ``640x480`` -> (width, height), even numbers."""
    try:
        w, _, h = text.lower().partition("x")
        size = (int(w), int(h or w))
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a size: {text!r} (use 512 or 640x480)") from None
    if not all(16 <= s <= 4096 and s % 2 == 0 for s in size):
        raise argparse.ArgumentTypeError(f"size {text!r} out of range (even numbers from 16 to 4096)")
    return size


def run_main(prog: str, body: Callable[[], int]) -> int:
    """Runs ``body``; user mistakes (FdError) and closed pipes become one line and exit 1."""
    from common.errors import FdError

    try:
        return body()
    except FdError as exc:
        sys.stderr.write(f"{prog}: {exc}\n")
    except BrokenPipeError:
        sys.stderr.write(f"{prog}: the other end of the pipe was closed\n")
    except KeyboardInterrupt:
        return 130
    return 1
