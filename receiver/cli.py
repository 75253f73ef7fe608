"""fd-recv: an fd stream in (stdin, a file or a socket), rendered face video out."""

import argparse
import json
import sys
import time

from facedeform.common.cli import ArgumentParser, check_output, number, parse_size, run_main
from facedeform.receiver.face_view import LOOKS

EPILOG = """examples:
  fd-send talk.mp4 | fd-recv -o out.mp4
  fd-send talk.mp4 | fd-recv --serve :8080 -o out.mp4      (watch at http://127.0.0.1:8080/)
  fd-recv talk.fd -o out.y4m --size 256 --dump decoded.npz
  fd-recv talk.fd --face me.fdface --look face -o face-only.mp4
  fd-recv --listen udp://:5000 --face me.fdface --serve :8080
  fd-recv --listen tcp://0.0.0.0:5000 -o call.mp4 --json
  fd-recv --listen udp://:5000 --key call.key -o call.mp4
"""


def parse_args(argv=None) -> argparse.Namespace:
    p = ArgumentParser(
        prog="fd-recv", epilog=EPILOG,
        description="Decode an fd stream and render the face it carries: the face mesh is deformed "
                    "by each frame's parameters and drawn with a Z-buffer and Phong shading, with the "
                    "person's own texture when their face model is known. A stream with a picture layer "
                    "(fd-send --bitrate with a face's reference picture) may have a frame wait for the "
                    "layer's next video frame, to be drawn from both (at most fd-send --ahead).")
    p.add_argument("input", nargs="?", help="stream file, or - for stdin (default)")
    p.add_argument("--listen", metavar="URL",
                   help="receive from the network instead: udp://HOST:PORT (one packet per datagram) or "
                        "tcp://HOST:PORT (one connection); HOST defaults to 127.0.0.1")
    p.add_argument("-o", "--output", metavar="FILE",
                   help="video file (.mp4, .mkv, .mov: H.264), .y4m, or - for Y4M on stdout "
                        "(default, unless --serve)")
    p.add_argument("--size", type=parse_size, metavar="WxH",
                   help="output size in pixels: 640x480, or 640 for that width and the height that keeps the "
                        "picture's proportions (default: the source's, as the stream says, else the reference "
                        "picture's, else 512x512); even numbers, as 4:2:0 video halves each side for colour")
    p.add_argument("--look", choices=LOOKS, metavar="LOOK",
                   help="picture: the person's whole reference picture warped by the moving face (default "
                        "when the face model has one); face: their textured face alone (default for a model "
                        "with a texture only; a model without one, such as the generic face, is drawn as "
                        "shaded); shaded: the face mesh shaded as in the paper (default for the "
                        "generic face)")
    p.add_argument("--fps", type=float, metavar="N",
                   help="output frame rate (default: the stream's); frames are repeated or dropped to meet it")
    p.add_argument("--face", metavar="FILE",
                   help="the sender's face model (fd-enroll); default: the model the stream carries, "
                        "else the generic face (a face paced beside the frames, fd-send --paced-face: the "
                        "generic face, then its preview, then the face, each from when it has come)")
    p.add_argument("--faces", metavar="DIR",
                   help="a folder of face models the receiver holds, each named by its id (ID.fdface, the "
                        "sha256 fd-enroll prints): a stream that names one is drawn with it from its first "
                        "frame (fd-send --face-by-id, or a face in the stream that need not be waited for), "
                        "and a face model that comes whole in a stream is kept there for the next call "
                        "(sealed with --key if given)")
    p.add_argument("--key", metavar="FILE",
                   help="the stream is sealed with this pre-shared key (fd-keygen): packets that fail "
                        "authentication or replay are dropped and counted; also opens a sealed --face file")
    p.add_argument("--serve", metavar="HOST:PORT",
                   help="also show the video and the call's statistics in a browser, at http://HOST:PORT/ "
                        "(HOST defaults to 127.0.0.1: --serve :8080); needs no display. A file's or a pipe's "
                        "last frame stays served until Ctrl-C; a call over --listen ends with the call")
    p.add_argument("--headers", metavar="DIR",
                   help="with --listen udp://: keep each call's stream header in DIR, and start a call whose "
                        "header is there at its first keyframe (a receiver restarted mid-call) instead of "
                        "waiting for the sender to repeat it")
    p.add_argument("--no-reports", action="store_true",
                   help="with --listen udp://: send the sender no loss reports (by default one of 21 bytes "
                        "every 0.5 s while the stream comes, so that fd-send sends its copies only while "
                        "datagrams are lost, and a paced face only until it is held; without them it always "
                        "sends the copies, about twice the bits, and a paced face round the whole call)")
    p.add_argument("--timeout", type=number(0.1, 3600), default=5.0, metavar="S",
                   help="with --listen: end after S seconds without data once the stream has started (default 5)")
    p.add_argument("--dump", metavar="FILE.npz", help="also write the decoded parameters of every frame")
    p.add_argument("--json", action="store_true", help="statistics as one JSON object, the last line on stderr")
    p.add_argument("-q", "--quiet", action="store_true", help="no statistics or progress on stderr")
    args = p.parse_args(argv)
    if args.listen and args.input is not None:
        p.error("give an input file or --listen URL, not both")
    if args.fps is not None and not 0 < args.fps <= 1000:
        p.error("--fps must be above 0 and at most 1000")
    if args.output is None and not args.serve:
        args.output = "-"
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    return run_main("fd-recv", lambda: _run(args))


def _run(args) -> int:
    from facedeform.codec.face_file.format import Face
    from facedeform.common.errors import InputError
    from facedeform.common.keys import read_key
    from facedeform.common.progress import progress_for
    from facedeform.receiver.face_cache import FaceCache
    from facedeform.receiver.output import open_writer
    from facedeform.receiver.session import ReceiveSession
    from facedeform.receiver.transport import Listener, open_file
    from facedeform.receiver.viewer import Viewer, live_stats

    if args.output == "-" and sys.stdout.isatty():
        raise InputError("refusing to write video to a terminal: use -o FILE.mp4, or --serve :8080 to watch "
                         "in a browser")
    for option, path in (("-o", args.output), ("--dump", args.dump)):
        if path:
            check_output(path, option, (args.input, args.face))
    key = read_key(args.key) if args.key else None
    face = Face.load(args.face, key).model if args.face else None
    viewer = Viewer(args.serve) if args.serve else None
    if viewer and not args.quiet:
        print(f"fd-recv: watch at {viewer.url}", file=sys.stderr, flush=True)

    def open_sinks(fps: float, size: tuple[int, int]) -> list:
        sinks = [open_writer(args.output, fps, size, sys.stdout.buffer)] if args.output else []
        return sinks + ([_Shown(viewer)] if viewer else [])

    from facedeform.codec.render.render import WARMING_UP, warm_up
    from facedeform.common.progress import slow_step

    # before the stream: a call's first frame waits only for the call, and the first run after an
    # install, which compiles the rasteriser, says so instead of seeming to hang
    with slow_step("fd-recv", WARMING_UP, args.quiet or args.json):
        warm_up()
    listener = Listener(args.listen, args.timeout, key, args.headers, not args.no_reports) if args.listen else None
    if listener and not args.quiet:
        print(f"fd-recv: listening on {listener.url}", file=sys.stderr, flush=True)
    source = listener.source() if listener else open_file(args.input or "-", sys.stdin.buffer, key)
    faces = FaceCache(args.faces, key) if args.faces else None
    session = ReceiveSession(open_sinks, args.size, face, f"--face {args.face}", args.fps, look=args.look,
                             dump=args.dump, faces=faces)
    size = source.size
    progress = progress_for("fd-recv", args.quiet or args.json) if size else None
    update = (lambda: progress.update(source.consumed, size, f"{session.frames} frames")) \
        if progress and size else None
    started = time.perf_counter()
    if viewer:
        viewer.stats = live_stats(session, source, started)
    try:
        try:
            session.run(source, update)
        finally:
            if progress:
                progress.close()
            session.close()  # the output file is whole from here on
            if session.frames:
                if args.json:
                    print(json.dumps(session.stats(time.perf_counter() - started)), file=sys.stderr)
                elif not args.quiet:
                    print("fd-recv: " + session.summary(time.perf_counter() - started), file=sys.stderr)
        if viewer and not listener:
            _linger(viewer, args.quiet)
    finally:
        if viewer:
            viewer.close()
    return 0


class _Shown:
    """The viewer as one of the session's sinks, closed by fd-recv itself: it may outlast them."""

    def __init__(self, viewer) -> None:
        self.write = viewer.write

    def close(self) -> None:
        pass


def _linger(viewer, quiet: bool) -> None:
    """After a file or pipe's stream has ended, --serve keeps showing its last frame and statistics
    until Ctrl-C (a call over --listen ends with the call). The line saying so is inside the wait: a
    Ctrl-C that comes as soon as it is read (a loaded machine, the main thread not yet past the print)
    still ends the wait, not the program with 130."""
    try:
        if not quiet:
            print(f"fd-recv: the stream has ended; {viewer.url} shows its last frame until Ctrl-C",
                  file=sys.stderr, flush=True)
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass


if __name__ == "__main__":
    sys.exit(main())
