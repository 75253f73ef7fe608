"""fd-send: a video of a talking face in, an fd stream out (stdout by default)."""

import argparse
import sys
import time

from codec.cli import ArgumentParser, run_main

EPILOG = """examples:
  fd-send talk.mp4 | fd-recv -o out.mp4
  fd-send talk.mp4 -o talk.fd --dump talk-params.npz
"""


def parse_args(argv=None) -> argparse.Namespace:
    p = ArgumentParser(
        prog="fd-send", epilog=EPILOG,
        description="Track a talking face in a video and send its motion as a few numbers per frame: "
                    "the jaw angle and the displacement of four mouth points (Akimoto, Mase and "
                    "Suenaga's model) plus head rotation.")
    p.add_argument("input", help="video file (anything OpenCV reads: mp4, mpg, avi, ...)")
    p.add_argument("-o", "--output", default="-", metavar="FILE",
                   help="where the stream goes: a file, or - for stdout (default)")
    p.add_argument("--quality", type=int, choices=range(1, 6), default=3, metavar="1-5",
                   help="quantiser fineness, 1 (coarse, fewest bits) to 5 (fine); each level halves the "
                        "steps of the one below (default 3: 0.25 degree, 0.002 face heights)")
    p.add_argument("--frames-per-packet", type=int, choices=range(1, 33), default=2, metavar="N",
                   help="frames sent together (1-32): fewer framing bits, N-1 frames more latency (default 2)")
    p.add_argument("--dump", metavar="FILE.npz",
                   help="also write per-frame landmarks, head pose and unquantised parameters")
    p.add_argument("-q", "--quiet", action="store_true", help="no statistics on stderr")
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    return run_main("fd-send", lambda: _run(args))


def _run(args) -> int:
    from codec.errors import InputError
    from sender.session import SendSession

    if args.output == "-" and sys.stdout.isatty():
        raise InputError("refusing to write a binary stream to a terminal: pipe it (| fd-recv) or use -o FILE")
    out = sys.stdout.buffer if args.output == "-" else _open_output(args.output)
    started = time.perf_counter()
    session = SendSession(args.input, args.quality, args.frames_per_packet)
    try:
        for chunk in session.stream():
            out.write(chunk)
            out.flush()
    finally:
        if out is not sys.stdout.buffer:
            out.close()
        if args.dump and session.frames:
            session.write_dump(args.dump)
    if not args.quiet:
        print("fd-send: " + session.summary(time.perf_counter() - started), file=sys.stderr)
    return 0


def _open_output(path: str):
    from codec.errors import InputError

    try:
        return open(path, "wb")
    except OSError as exc:
        raise InputError(f"{path}: cannot write ({exc.strerror})") from None


if __name__ == "__main__":
    sys.exit(main())
