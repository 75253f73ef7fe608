"""What every command-line tool of the project shares: one-line errors and exit codes."""

import argparse
import math
import os
import sys
from collections.abc import Callable

from facedeform.common.limits import MAX_SIDE


class ArgumentParser(argparse.ArgumentParser):
    """argparse, but a wrong argument is one line on stderr (exit 2), as every other user mistake;
    every tool says its version (``--version``, before anything heavy is loaded)."""

    def __init__(self, **kwargs) -> None:
        from facedeform import __version__

        kwargs.setdefault("formatter_class", argparse.RawDescriptionHelpFormatter)
        super().__init__(**kwargs)
        self.add_argument("--version", action="version", version=f"%(prog)s {__version__}")

    def error(self, message: str):
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def parse_size(text: str) -> tuple[int, int]:
    """An argparse type for an output size: ``640x480`` -> (640, 480), or ``640`` -> (640, 0): the
    width, the height to keep the picture's proportions (:func:`fitted`). Even numbers: H.264 and
    Y4M store colour at half the size each way (4:2:0)."""
    try:
        w, _, h = text.lower().partition("x")
        size = (int(w), int(h) if h else 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a size: {text!r} (use 640 or 640x480)") from None
    if not all(16 <= s <= MAX_SIDE and s % 2 == 0 for s in (size if size[1] else size[:1])):
        raise argparse.ArgumentTypeError(f"size {text!r} out of range (even numbers from 16 to {MAX_SIDE}: "
                                         "4:2:0 video halves each side for colour)")
    return size


def fitted(size: tuple[int, int], natural: tuple[int, int]) -> tuple[int, int]:
    """``size`` from :func:`parse_size` made whole: a height of 0 becomes the even height that
    keeps ``natural``'s (width, height) proportions at that width, within the limits."""
    width, height = size
    if height:
        return size
    return width, min(MAX_SIDE, max(16, 2 * round(width * natural[1] / natural[0] / 2)))


def number(lo: float | None = None, hi: float | None = None, kind: type = float) -> Callable[[str], float]:
    """An argparse type for a finite number in [lo, hi] (None: unbounded): NaN, infinities and
    values out of range are refused with one line, as every other wrong argument."""
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a{'n integer' if kind is int else ' number'}: {text!r}") from None
        if not in_range(value, lo, hi):
            raise argparse.ArgumentTypeError(f"{text!r} is out of range ({describe_range(lo, hi)})")
        return value

    return parse


def in_range(value: float, lo: float | None, hi: float | None) -> bool:
    """Finite and within [lo, hi] (None: no bound on that side)."""
    return math.isfinite(value) and (lo is None or value >= lo) and (hi is None or value <= hi)


def describe_range(lo: float | None, hi: float | None) -> str:
    """[lo, hi] in words."""
    if hi is None:
        return f"at least {lo:g}"
    return f"at most {hi:g}" if lo is None else f"{lo:g} to {hi:g}"


def check_output(path: str, option: str, inputs: tuple[str | None, ...] = ()) -> None:
    """Refuses, before any work, an output file that cannot be written (missing or read-only folder, a
    folder itself) or that is one of the ``inputs`` (writing would destroy what is being read)."""
    from facedeform.common.errors import InputError

    if path == "-" or "://" in path:
        return
    folder = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path):
        raise InputError(f"{option} {path}: is a folder, not a file")
    if not os.path.isdir(folder):
        raise InputError(f"{option} {path}: the folder {folder} does not exist")
    if not os.access(folder, os.W_OK) or (os.path.exists(path) and not os.access(path, os.W_OK)):
        raise InputError(f"{option} {path}: not writable")
    for source in inputs:
        if source and os.path.exists(source) and os.path.exists(path) and os.path.samefile(source, path):
            raise InputError(f"{option} {path}: is the input; refusing to write over what is being read")


def run_main(prog: str, body: Callable[[], int]) -> int:
    """Runs ``body``; user mistakes (FdError) and closed pipes become one line and exit 1."""
    from facedeform.common.errors import FdError

    try:
        return body()
    except FdError as exc:
        sys.stderr.write(f"{prog}: {exc}\n")
    except BrokenPipeError:
        _drop_stdout()
        sys.stderr.write(f"{prog}: the other end of the pipe was closed\n")
    except OSError as exc:  # a full disk, a read-only folder, a device that failed: the system's words
        _drop_stdout()
        where = f"{exc.filename}: " if exc.filename else ""
        sys.stderr.write(f"{prog}: {where}{exc.strerror or exc}\n")
    except KeyboardInterrupt:
        return 130
    return 1


def _drop_stdout() -> None:
    """Points stdout at /dev/null, so that the interpreter's last flush of what could not be
    written (a full disk, a closed pipe) does not print a second complaint."""
    try:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except (OSError, ValueError):  # no stdout to speak of
        pass
