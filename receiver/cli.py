"""fd-recv: an fd stream in (stdin by default), rendered face video out."""

import argparse
import sys
import time

from codec.cli import ArgumentParser, parse_size, run_main

EPILOG = """examples:
  fd-send talk.mp4 | fd-recv -o out.mp4
  fd-send talk.mp4 | fd-recv -o - | ffplay -
  fd-recv talk.fd -o out.y4m --size 256 --dump decoded.npz
"""


def parse_args(argv=None) -> argparse.Namespace:
    p = ArgumentParser(
        prog="fd-recv", epilog=EPILOG,
        description="Decode an fd stream and render the face it carries: the base face mesh is "
                    "deformed by each frame's parameters and drawn with a Z-buffer and Phong shading.")
    p.add_argument("input", nargs="?", default="-", help="stream file, or - for stdin (default)")
    p.add_argument("-o", "--output", default="-", metavar="FILE",
                   help="video file (.mp4, .mkv, .mov: H.264), .y4m, or - for Y4M on stdout (default)")
    p.add_argument("--size", type=parse_size, default=(512, 512), metavar="WxH",
                   help="output size in pixels, e.g. 512 (default) or 640x480")
    p.add_argument("--dump", metavar="FILE.npz", help="also write the decoded parameters of every frame")
    p.add_argument("-q", "--quiet", action="store_true", help="no statistics on stderr")
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    return run_main("fd-recv", lambda: _run(args))


def _run(args) -> int:
    from codec.errors import InputError
    from receiver.session import ReceiveSession

    if args.output == "-" and sys.stdout.isatty():
        raise InputError("refusing to write video to a terminal: use -o FILE.mp4 or pipe it (| ffplay -)")
    source = _open_input(args.input)
    session = ReceiveSession(args.output, args.size, sys.stdout.buffer)
    started = time.perf_counter()
    try:
        session.run(source)
    finally:
        session.close()
        if args.dump and session.decoded:
            session.write_dump(args.dump)
        if not args.quiet and session.decoded:
            print("fd-recv: " + session.summary(time.perf_counter() - started), file=sys.stderr)
    return 0


def _open_input(path: str):
    from codec.errors import InputError

    if path == "-":
        return sys.stdin.buffer
    try:
        return open(path, "rb")
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None


if __name__ == "__main__":
    sys.exit(main())
