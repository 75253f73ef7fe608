"""fd-send: a talking face in (video file, image sequence or camera), an fd stream out."""

import argparse
import json
import sys

from facedeform.codec.model.regions import RULES
from facedeform.common.cli import ArgumentParser, check_output, number, run_main
from facedeform.protocol.quantise import DEFAULT_QUALITY
from facedeform.protocol.secure import TAG_BITS
from facedeform.sender.analysis import LAYOUT_NAMES
from facedeform.sender.config import (
    BITRATE,
    DATAGRAM_FRAMES,
    LEVEL_SHARE,
    LIMITS,
    QUALITY_RATES,
    SPEAKER_RATE,
    STREAM_FRAMES,
    SendConfig,
    default,
)

EPILOG = """examples:
  fd-send talk.mp4 | fd-recv -o out.mp4
  fd-send talk.mp4 -o talk.fd --dump talk-params.npz --params full
  fd-send frames/%04d.png --fps 30 -o tcp://127.0.0.1:5000
  fd-send --camera 0 -o udp://127.0.0.1:5000
  fd-send talk.mp4 --key call.key -o udp://127.0.0.1:5000
  fd-send --camera 0 --face me.fdface --paced-face --bitrate 4 -o tcp://127.0.0.1:5000
"""


def parse_args(argv=None) -> argparse.Namespace:
    p = ArgumentParser(
        prog="fd-send", epilog=EPILOG,
        description="Track a talking face and send its motion as a few numbers per frame: the jaw "
                    "angle and the displacement of mouth points (Akimoto, Mase and Suenaga's model, "
                    "with more lip points, or the person's own motion basis from fd-enroll) plus head "
                    "rotation.")
    p.add_argument("input", nargs="?",
                   help="video file (anything OpenCV or PyAV reads), a directory of images, "
                        "or a numbered pattern such as frames/%%04d.png")
    p.add_argument("--camera", type=number(0, None, kind=int), metavar="N",
                   help="read camera N instead of a file (Ctrl-C stops)")
    p.add_argument("--fps", type=number(0.1, 1000), default=25.0,
                   help="frame rate of an image sequence, 0.1-1000 (default 25)")
    p.add_argument("--realtime", action="store_true",
                   help="read the input at its frame rate, as a camera delivers frames (a live call from a "
                        "file, e.g. with -o udp://HOST:PORT); by default a file is read as fast as it is analysed")
    p.add_argument("-o", "--output", default="-", metavar="DEST",
                   help="a file, - for stdout (default), tcp://HOST:PORT (connect, waiting up to 5 s for the "
                        "receiver, and write the stream) or udp://HOST:PORT (one packet per datagram, behind "
                        "copies of the ones before against loss (--redundancy), the header repeated for "
                        "receivers that join late)")
    p.add_argument("--params", choices=LAYOUT_NAMES, default=default("layout"),
                   help="auto (default): personal when the --face file carries a motion basis, else mouth; "
                        "paper: the paper's 13 parameters (jaw angle, four mouth points) and head rotation; "
                        "full: the paper's plus brows, lids, cheeks and head translation; "
                        "mouth: the paper's plus six more lip points and jaw translation; "
                        "personal: the coefficients of the person's own motion basis and head rotation "
                        "(needs --face from fd-enroll of a clip of them talking)")
    p.add_argument("--rule", choices=RULES, default=default("rule"),
                   help="deformation rule, named in the stream header: refined (default: the project's mouth "
                        "slit and rounded lower lip) or paper (the paper's equations (1) and (2) exactly); "
                        "--params paper alone keeps refined: the paper exactly is --params paper --rule paper")
    p.add_argument("--face", metavar="FILE.fdface",
                   help="the person's face model from fd-enroll: fitted here and carried once at the start "
                        "of the stream (its bytes are counted apart from the per-frame rate); default: the "
                        "generic base face")
    p.add_argument("--face-by-id", action="store_true",
                   help="with --face, send only the model's id: the receiver holds the file (fd-recv --face)")
    p.add_argument("--paced-face", action="store_true",
                   help="with --face and --bitrate (or --quality), send the face model beside the frames "
                        "within the rate, a coarse preview first, instead of all before the first frame: the "
                        "receiver draws at once (the generic face, then the preview, then the face); for live "
                        "links (a file then starts with the generic face). Over udp:// it goes round until "
                        "the receiver reports it held, or the whole call where none reports, so that a "
                        "lost chunk comes again and a receiver that joins late gets it too")
    p.add_argument("--neutral", type=number(*LIMITS["neutral"], kind=int), metavar="FRAME",
                   help="frame index (from 0) of the person's rest face; default: the frame of the "
                        "first second with the mouth most closed, its eyes open")
    p.add_argument("--smoothing", type=number(*LIMITS["smoothing"]), default=default("smoothing"), metavar="S",
                   help="temporal smoothing strength: 0 off, 1 (default), 2 twice as strong "
                        f"(steadier and cheaper, slower to follow), at most {LIMITS['smoothing'][1]:g}")
    rate = p.add_mutually_exclusive_group()
    rate.add_argument("--bitrate", type=number(BITRATE[0] / 1000, BITRATE[1] / 1000),
                      metavar="KBPS",
                      help="the stream's rate after its header, in kbit/s (--quality names five). With a --face "
                           "that has a reference picture (fd-enroll's default) and a rate where it pays, the "
                           "parameters aim at 20 %% of it (at least 1.2 kbit/s) and the rest carries the real frame "
                           "as a small VP9 video coded from the model's own picture, drawn "
                           "where the face model cannot show the frame (the picture layer: what a turn, a lean or "
                           "a moving camera uncovers), the whole kept within 10 %% of the rate over any 2 s; more "
                           "kbit/s, a better picture (none below about 3 kbit/s at 256x256). Otherwise the "
                           "finest quantiser level that codes the call's first second within it, with the dead "
                           "zone widened as the call goes where livelier talking costs more, and a coarser "
                           "level (from a keyframe) where that is not enough. Over udp:// it counts "
                           "the copies (--redundancy) and the header's repeats for late joiners (all but those "
                           "of the first 4 s, which are one-off like the header); where the copies leave the "
                           "picture layer too little, it runs while fd-recv reports a link that loses nothing")
    rate.add_argument("--quality", type=number(*LIMITS["quality"], kind=int), metavar="1-5",
                      help="the picture's quality as a --bitrate: " + ", ".join(
                          f"{q} {r / 1000:g}" for q, r in QUALITY_RATES.items()) + " kbit/s. 1 is the face "
                           "model alone; from 2 on, with a --face that has a reference picture, the rest of the "
                           "rate carries the picture layer, and every step up buys picture")
    rate.add_argument("--level", type=number(*LIMITS["level"], kind=int), metavar="1-5",
                      help="instead of a rate, the parameters' quantiser level, 1 (coarse, fewest bits) to 5 "
                           f"(fine); each level halves the steps of the one below. Default: {DEFAULT_QUALITY}; with a "
                           f"--face from fd-enroll (its own motion basis) the finest level that codes the speaker's "
                           f"first second within {100 * LEVEL_SHARE:g} %% of {SPEAKER_RATE / 1000:g} kbit/s, with a "
                           f"dead zone widened where the call later costs more")
    p.add_argument("--ahead", type=number(*LIMITS["ahead"]), default=default("ahead"), metavar="SECONDS",
                   help="with the picture layer, how long fd-recv may hold a frame for the layer's next video "
                        "frame, to draw the frames between two of them from both instead of from the last "
                        f"alone ({_span('ahead')}; default %(default)s): the picture between video frames no "
                        "longer drifts, at up to this much more latency; 0: each frame drawn as it arrives")
    p.add_argument("--dead-zone", type=number(*LIMITS["dead_zone"]), default=default("dead_zone"), metavar="STEPS",
                   help="a parameter is resent only once it is this many quantiser steps from what the "
                        f"receiver shows ({_span('dead_zone')}; default %(default)s): tracker jitter below it costs "
                        "no bits and a still face does not flicker, at up to this many steps of error; 0.5 is "
                        "plain rounding (error at most half a step), which the head's pose over a reference "
                        "picture always gets")
    p.add_argument("--no-basis", action="store_true",
                   help="quantise each parameter on its own; by default the stream codes the principal "
                        "components of the first second's motion (head pose apart), which costs fewer bits "
                        "for the same error (docs/bitstream.md); the personal layout never does, its motion "
                        "basis being one already")
    p.add_argument("--send-every", type=number(*LIMITS["divisor"], kind=int), default=default("divisor"),
                   metavar="N",
                   help=f"send one frame in N ({_span('divisor')}; default %(default)s: every frame); the "
                        "receiver interpolates the others linearly: fewer bits, but motion faster than the frames "
                        "sent is lost (docs/bitstream.md) and the receiver shows each frame N-1 frames later")
    p.add_argument("--frames-per-packet", type=number(*LIMITS["frames_per_packet"], kind=int),
                   default=default("frames_per_packet"), metavar="N",
                   help=f"frames sent together ({_span('frames_per_packet')}): fewer framing bits, N-1 frames "
                        f"more latency (sent frames: times --send-every) (default {STREAM_FRAMES}, over udp:// "
                        f"{DATAGRAM_FRAMES}: a burst of lost datagrams then costs fewer frames)")
    p.add_argument("--redundancy", type=number(*LIMITS["redundancy"], kind=int), default=default("redundancy"),
                   metavar="N",
                   help=f"over udp://, the frames packets before it that each datagram carries again "
                        f"({_span('redundancy')}; default %(default)s): up to N datagrams lost in a row cost no "
                        "frame, and each copy adds about the frames' own bits again (docs/bitstream.md, Bursts); "
                        "while fd-recv reports no loss, none, two frames a datagram and half the keyframes "
                        "(Loss reports)")
    p.add_argument("--key", metavar="FILE",
                   help="encrypt and authenticate every packet (face model included) with this pre-shared "
                        "key (fd-keygen; docs/security.md); also opens a --face file sealed with it")
    p.add_argument("--tag-bits", type=int, choices=TAG_BITS, metavar="N",
                   help=f"with --key: authentication tag length, {default('tag_bits')} (default) to "
                        f"{TAG_BITS[-1]} in steps of 8")
    p.add_argument("--dump", metavar="FILE.npz",
                   help="also write per-frame landmarks, pose-free targets, head pose and unquantised parameters")
    p.add_argument("--json", action="store_true", help="statistics as one JSON object on stderr")
    p.add_argument("-q", "--quiet", action="store_true", help="no statistics on stderr")
    args = p.parse_args(argv)
    if (args.input is None) == (args.camera is None):
        p.error("give an input file or --camera N (one of them)")
    if args.tag_bits is not None and args.key is None:
        p.error("--tag-bits goes with --key FILE")
    if args.face_by_id and args.face is None:
        p.error("--face-by-id goes with --face FILE")
    if args.paced_face and (args.face is None or args.face_by_id):
        p.error("--paced-face goes with --face FILE (without --face-by-id)")
    if args.paced_face and args.bitrate is None and args.quality is None:
        p.error("--paced-face goes with --bitrate KBPS or --quality N, the rate it is paced within")
    return args


def _span(name: str) -> str:
    lo, hi = LIMITS[name]
    return f"{lo:g}-{hi:g}"


def main(argv=None) -> int:
    args = parse_args(argv)
    return run_main("fd-send", lambda: _run(args))


def _run(args) -> int:
    from facedeform.codec.face_file.format import Face
    from facedeform.common.keys import read_key
    from facedeform.common.progress import progress_for
    from facedeform.sender.session import SendSession
    from facedeform.sender.sources import PacedSource, open_source
    from facedeform.sender.transport import check_destination, open_sink

    check_output(args.output, "-o", (args.input,))
    check_destination(args.output)
    if args.dump:
        check_output(args.dump, "--dump", (args.input,))
    key = read_key(args.key) if args.key else None
    source = open_source(args.input, args.camera, args.fps)
    if args.realtime and args.camera is None:
        source = PacedSource(source)
    progress = progress_for("fd-send", args.quiet or args.json) if source.length else None
    face = Face.load(args.face, key) if args.face else None  # a sealed file opens with the stream's key
    config = SendConfig(args.level, args.frames_per_packet, args.params, args.neutral, args.smoothing,
                        embed_face=not args.face_by_id, key=key, tag_bits=args.tag_bits or default("tag_bits"),
                        dead_zone=args.dead_zone, bitrate=None if args.bitrate is None else 1000 * args.bitrate,
                        basis=not args.no_basis, divisor=args.send_every,
                        datagrams=args.output.startswith("udp://"), redundancy=args.redundancy, rule=args.rule,
                        quality=args.quality, paced_face=args.paced_face, ahead=args.ahead)
    if face is not None and config.bitrate is not None and config.picture_layer:
        from facedeform.codec.render.render import WARMING_UP, warm_up
        from facedeform.common.progress import slow_step

        with slow_step("fd-send", WARMING_UP, args.quiet or args.json):  # the picture layer draws what is sent
            warm_up()
    session = SendSession(source, config, args.dump, face)
    sink = None
    try:
        for packets in session.packets():
            if sink is None:  # opened only once there is something to send
                sink = open_sink(args.output, sealed=session.sealed)
                session.feedback = getattr(sink, "report", None)  # a receiver's loss reports over UDP
            sink.write(packets)
            if progress:
                progress.update(session.frame_count, source.length, f"{session.frame_count} frames")
    except KeyboardInterrupt:  # a camera runs until stopped: close the stream properly
        if sink is not None:
            sink.write(session.end())
    finally:
        if progress:
            progress.close()
        if sink is not None:
            sink.close()
        session.close()
    if args.json:
        print(json.dumps(session.stats()), file=sys.stderr)
    elif not args.quiet:
        print("fd-send: " + session.summary(), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
