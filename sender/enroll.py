"""fd-enroll: a person's face model from a video of them, as one file to share before a call
(sender/enrolment.py does the work; ``facedeform.enroll`` is the same from Python)."""

import argparse
import sys

from facedeform.codec.face_file.format import BUDGET, COARSEST_CRF, HD_BUDGET, PICTURE_FORMAT, QUALITY
from facedeform.common.cli import ArgumentParser, check_output, number, run_main
from facedeform.common.parameters import MAX_COMPONENTS
from facedeform.sender.enrolment import MOTION_PATTERNS, TEXTURE_SIDES, TEXTURE_SIZE
from facedeform.sender.motion import FRAMES_PER_PATTERN

EPILOG = """examples:
  fd-enroll me.mp4 -o me.fdface
  fd-enroll me.mp4 --frame 12 -o me.fdface
  fd-send talk.mp4 --face me.fdface | fd-recv --face me.fdface -o out.mp4
  fd-send talk.mp4 --face me.fdface --params personal | fd-recv -o out.mp4
"""
def parse_args(argv=None) -> argparse.Namespace:
    p = ArgumentParser(
        prog="fd-enroll", epilog=EPILOG,
        description="Make a person's face model from a video of them: the mesh from their tracked "
                    "landmarks in a neutral frame, the texture from that frame. Prints the model's id "
                    "(the sha256 of the file), which streams made for it carry.")
    p.add_argument("input", help="video file, a directory of images, or a numbered pattern such as f/%%04d.png")
    p.add_argument("-o", "--output", required=True, metavar="FILE", help="face model to write, e.g. me.fdface")
    pick = p.add_mutually_exclusive_group()
    pick.add_argument("--frame", type=int, metavar="N", help="use frame N (from 0), which must show the face")
    pick.add_argument("--auto", action="store_true",
                      help="choose the frame (default): of the first seconds with a face, the one with the "
                           "mouth most closed and the head nearest to frontal, its eyes open")
    p.add_argument("--seconds", type=number(0.04, 3600), default=2.0, metavar="S",
                   help="how much of the clip --auto chooses from, counted from the first face (default 2)")
    p.add_argument("--texture-size", type=int, default=TEXTURE_SIZE, metavar="PX",
                   help=f"texture width and height in texels, {TEXTURE_SIDES[0]}-{TEXTURE_SIDES[1]} (default "
                        f"{TEXTURE_SIZE}); with --no-picture only: the reference picture textures the face otherwise")
    p.add_argument("--motion", type=int, default=MOTION_PATTERNS, metavar="N",
                   help=f"most patterns in the person's motion basis, 0-{MAX_COMPONENTS} (default {MOTION_PATTERNS}; "
                        f"0: none); a clip gets as many as it has frames for, {FRAMES_PER_PATTERN} frames of "
                        "talking per pattern")
    p.add_argument("--motion-over", choices=("rest", "paper"), default="rest",
                   help="rest: the patterns span the whole mouth and jaw motion and replace the paper's "
                        "parameters in --params personal (default: fewest bits for the fidelity); paper: "
                        "they span what the paper's 13 parameters leave over and are sent after them")
    p.add_argument("--motion-seconds", type=number(0.04, 36000), default=60.0, metavar="S",
                   help="how much of the clip the motion basis, the picture's ring weights and the shut "
                        "eyes (the deepest blink, eyes open again within half a second) are learned from "
                        "(default 60)")
    p.add_argument("--no-picture", action="store_true",
                   help="leave out the reference picture (the whole neutral frame, AV1; docs/picture.md): "
                        "the receiver then draws the face alone")
    p.add_argument("--budget", type=int, metavar="BYTES",
                   help=f"the face model's most bytes, as far as a coarser reference picture can make it so (AV1 "
                        f"CRF {QUALITY[PICTURE_FORMAT]} up to {COARSEST_CRF}); default {BUDGET:,}, {HD_BUDGET:,} "
                        f"for a picture over 640x480: a 256x256 call's face in the stream within about 20 s at 4 "
                        "kbit/s; 0: no budget, the picture at its finest")
    p.add_argument("--key", metavar="FILE",
                   help="encrypt the face model at rest with this key (fd-keygen); fd-send and fd-recv open it "
                        "with the same --key")
    p.add_argument("-q", "--quiet", action="store_true", help="print only the id")
    args = p.parse_args(argv)
    if args.frame is not None and args.frame < 0:
        p.error("--frame takes a frame index from 0")
    if not TEXTURE_SIDES[0] <= args.texture_size <= TEXTURE_SIDES[1]:
        p.error(f"--texture-size must be {TEXTURE_SIDES[0]} to {TEXTURE_SIDES[1]}")
    if not 0 <= args.motion <= MAX_COMPONENTS:
        p.error(f"--motion must be 0 to {MAX_COMPONENTS}")
    if args.budget is not None and args.budget < 0:
        p.error("--budget takes a number of bytes, or 0 for none")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    return run_main("fd-enroll", lambda: _run(args))


def _run(args) -> int:
    from facedeform.common.keys import read_key
    from facedeform.common.progress import progress_for
    from facedeform.sender.enrolment import enroll_face

    check_output(args.output, "-o", (args.input,))
    key = read_key(args.key) if args.key else None
    progress = progress_for("fd-enroll", args.quiet)
    update = (lambda done, total: progress.update(done, total, "learning how the face, hair and shoulders move")) \
        if progress else None
    try:
        made = enroll_face(args.input, args.frame, args.seconds, args.motion, args.motion_over, args.motion_seconds,
                           not args.no_picture, args.texture_size, update, args.budget)
    finally:
        if progress:
            progress.close()
    ident = made.face.save(args.output, key)
    print(ident)
    if not args.quiet:
        note = ""
        if args.motion:
            note = (f", motion basis of {made.patterns} patterns over the {args.motion_over} from "
                    f"{made.motion_frames} frames" if made.patterns else
                    f", no motion basis ({made.motion_frames} frames with a face; a pattern needs "
                    f"{FRAMES_PER_PATTERN})")
        print(f"fd-enroll: face model {ident[:12]} from frame {made.frame} (lip gap {made.lip_gap:.3f}, head turned "
              f"{made.head_turn:.1f} degrees){note}{_picture_note(made.face.data)}, {len(made.face.data)} "
              f"bytes in {args.output}{' (encrypted)' if key else ''}", file=sys.stderr)
    return 0


def _picture_note(data: bytes) -> str:
    from facedeform.codec.face_file.format import described

    info = described(data)
    if "picture" not in info:
        return ", no reference picture"
    size, width, height = info["picture"]
    mouth = f"open mouth {info['mouth'][0]} bytes" if "mouth" in info else "no open mouth"
    eyes = f"shut eyes {info['shut_eyes'][0]} bytes" if "shut_eyes" in info else "no blink seen"
    return f", reference picture {width}x{height} ({size} bytes, {mouth}, {eyes})"


if __name__ == "__main__":
    sys.exit(main())
