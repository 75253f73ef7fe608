"""fd-enroll: a person's face model from a video of them, as one file to share before a call.

The mesh is the person's own landmarks in a neutral frame with the head pose
removed, the texture their skin warped into the mesh's UV layout, and the
whole neutral frame is kept as the reference picture, with where the face sits
in it: the receiver then draws the whole picture, warped by the moving face
(codec/picture.py; ``fd-recv --face FILE``). When the
clip shows them talking, the file also carries their own motion basis
(sender/motion.py), which ``fd-send --params personal`` sends coefficients of.
"""

import argparse
import sys
from dataclasses import replace

import cv2
import numpy as np

from codec.motion_basis import MAX_COMPONENTS
from common.cli import ArgumentParser, number, run_main
from sender.motion import FRAMES_PER_PATTERN

EPILOG = """examples:
  fd-enroll me.mp4 -o me.fdface
  fd-enroll me.mp4 --frame 12 -o me.fdface
  fd-send talk.mp4 --face me.fdface | fd-recv --face me.fdface -o out.mp4
  fd-send talk.mp4 --face me.fdface --params personal | fd-recv -o out.mp4
"""
TEXTURE_SIZE = 256  # texels a side: about 20 KB as JPEG, detail for a 512-pixel rendering
#: A frame's distance from neutral: lip gap (over eye distance) in units of GAP_UNIT plus head
#: turn in units of ANGLE_UNIT, so a 0.05 gap (lips visibly parted) weighs as 10 degrees of turn.
GAP_UNIT, ANGLE_UNIT = 0.05, 10.0
#: On the dev clips each pattern up to 12 (the most their halves can teach) lowers the error at a given rate.
MOTION_PATTERNS = 12
#: The open mouth kept for the receiver: the enrolment window's widest lip gap (over eye distance)
#: past OPEN_GAP with the head turned under MOUTH_TURN degrees, cropped with MOUTH_MARGIN pixels.
OPEN_GAP, MOUTH_TURN, MOUTH_MARGIN = 0.08, 15.0, 3


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
                           "mouth most closed and the head nearest to frontal")
    p.add_argument("--seconds", type=number(0.04, 3600), default=2.0, metavar="S",
                   help="how much of the clip --auto chooses from, counted from the first face (default 2)")
    p.add_argument("--texture-size", type=int, default=TEXTURE_SIZE, metavar="PX",
                   help=f"texture width and height in texels, 64-1024 (default {TEXTURE_SIZE}); with --no-picture "
                        "only: the reference picture textures the face otherwise")
    p.add_argument("--motion", type=int, default=MOTION_PATTERNS, metavar="N",
                   help=f"most patterns in the person's motion basis, 0-{MAX_COMPONENTS} (default {MOTION_PATTERNS}; "
                        f"0: none); a clip gets as many as it has frames for, {FRAMES_PER_PATTERN} frames of "
                        "talking per pattern")
    p.add_argument("--motion-over", choices=("rest", "paper"), default="rest",
                   help="rest: the patterns span the whole mouth and jaw motion and replace the paper's "
                        "parameters in --params personal (default: fewest bits for the fidelity); paper: "
                        "they span what the paper's 13 parameters leave over and are sent after them")
    p.add_argument("--motion-seconds", type=number(0.04, 36000), default=60.0, metavar="S",
                   help="how much of the clip the motion basis learns from (default 60)")
    p.add_argument("--no-picture", action="store_true",
                   help="leave out the reference picture (the whole neutral frame, WebP; docs/picture.md): "
                        "the receiver then draws the face alone")
    p.add_argument("--key", metavar="FILE",
                   help="encrypt the face model at rest with this key (fd-keygen); fd-send and fd-recv open it "
                        "with the same --key")
    p.add_argument("-q", "--quiet", action="store_true", help="print only the id")
    args = p.parse_args(argv)
    if args.frame is not None and args.frame < 0:
        p.error("--frame takes a frame index from 0")
    if not 64 <= args.texture_size <= 1024:
        p.error("--texture-size must be 64 to 1024")
    if not 0 <= args.motion <= MAX_COMPONENTS:
        p.error(f"--motion must be 0 to {MAX_COMPONENTS}")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    return run_main("fd-enroll", lambda: _run(args))


def _run(args) -> int:
    from codec.face_file import decode_face, personal_face, save_face_file
    from codec.face_model import load_base_face
    from codec.texture import texture_from_frame
    from common.keys import read_key
    from sender.sources import open_source

    key = read_key(args.key) if args.key else None
    source = open_source(args.input)
    base = load_base_face()
    index, frame, landmarks, aligned, score = _neutral_frame(source, base, args.frame, args.seconds)
    rgb = cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
    picture, texture = None, None  # a reference picture textures the face too (codec/face_file.py)
    if args.no_picture:
        texture = texture_from_frame(rgb, landmarks[:, :2], base.uv, base.faces, args.texture_size)
    else:
        picture = reference_picture(rgb, landmarks, aligned, base,
                                    _open_mouth(open_source(args.input), base, args.seconds))
    motion, rings, frames = _learn(args, decode_face(personal_face(aligned, texture, base, picture=picture)), index)
    if rings is not None:
        picture = replace(picture, ring_weights=rings)
    data = personal_face(aligned, texture, base, motion, picture)
    note = ""
    if args.motion:
        note = (f", motion basis of {motion.components} patterns over the {args.motion_over} from {frames} frames"
                if motion is not None else
                f", no motion basis ({frames} frames with a face; a pattern needs {FRAMES_PER_PATTERN})")
    ident = save_face_file(data, args.output, key)
    print(ident)
    if not args.quiet:
        print(f"fd-enroll: face model {ident[:12]} from frame {index} (lip gap {score[0]:.3f}, head turned "
              f"{score[1]:.1f} degrees){note}{_picture_note(picture)}, {len(data)} bytes in {args.output}"
              f"{' (encrypted)' if key else ''}", file=sys.stderr)
    return 0


def reference_picture(rgb: np.ndarray, landmarks: np.ndarray, aligned: np.ndarray, base, mouth=None):
    """The whole (H, W, 3) RGB frame as the reference picture, with the projection that puts the
    face model made from ``aligned`` (``personal_face`` normalises it, in ``base``'s topology) onto
    its (468, 3) landmarks; ``mouth``: (RGB frame, landmarks) of a frame with the mouth open, or None."""
    from codec.face_model import ReferencePicture, mouth_vertices, normalise
    from sender.pose import STABLE_LANDMARKS, fit_pose, image_to_face_axes

    stable = list(STABLE_LANDMARKS)
    pose = fit_pose(image_to_face_axes(landmarks)[stable], normalise(np.asarray(aligned, np.float64))[stable])
    picture = ReferencePicture(rgb, pose.placement().matrix())
    if mouth is None:
        return picture
    frame, points = mouth[0], mouth[1][mouth_vertices(base), :2].astype(np.float64)
    (x0, y0), (x1, y1) = np.floor(points.min(axis=0)) - MOUTH_MARGIN, np.ceil(points.max(axis=0)) + MOUTH_MARGIN
    x0, y0 = int(max(x0, 0)), int(max(y0, 0))
    x1, y1 = int(min(x1, frame.shape[1])), int(min(y1, frame.shape[0]))
    return ReferencePicture(rgb, picture.projection, np.ascontiguousarray(frame[y0:y1, x0:x1]), points - [x0, y0])


def _open_mouth(source, base, seconds: float):
    """(RGB frame, (468, 3) landmarks) of the first ``seconds`` after the face appears with the
    mouth most open (head turned under MOUTH_TURN degrees), or None if it never opens OPEN_GAP."""
    from sender.calibrate import lip_gap
    from sender.pose import STABLE_LANDMARKS, fit_pose, image_to_face_axes
    from sender.tracker import FaceTracker

    tracker, stable = FaceTracker(), list(STABLE_LANDMARKS)
    window, seen, best, best_gap = max(1, round(seconds * source.fps)), 0, None, OPEN_GAP
    for frame in source.frames():
        landmarks = tracker.track(frame)
        if landmarks is None:
            continue
        seen += 1
        pose = fit_pose(image_to_face_axes(landmarks)[stable], base.vertices[stable])
        gap = float(lip_gap(landmarks))
        if gap > best_gap and np.linalg.norm(pose.head_rotation_vector()) < MOUTH_TURN:
            best, best_gap = (cv2.cvtColor(frame, cv2.COLOR_BGR2RGB), landmarks), gap
        if seen >= window:
            break
    return best


def _picture_note(picture) -> str:
    if picture is None:
        return ", no reference picture"
    from codec.face_file import encode_picture

    height, width = picture.image.shape[:2]
    mouth = "no open mouth" if picture.mouth is None else \
        f"open mouth {len(encode_picture(picture.mouth))} bytes"
    return f", reference picture {width}x{height} ({len(encode_picture(picture.image))} bytes, {mouth})"


def _learn(args, face, neutral: int):
    """(the person's MotionBasis or None, their ring weights or None, frames with a face seen), from
    one pass over the clip's first --motion-seconds: the motion basis when --motion asks for one
    (sender/motion.py), the ring weights when ``face`` has a reference picture
    (sender/motion_global.RingWeights), each frame tracked once for both."""
    from itertools import islice

    from common.progress import progress_for
    from sender.motion import learn_motion, residuals
    from sender.motion_global import RingWeights
    from sender.sources import open_source
    from sender.tracker import FaceTracker

    rings = None if face.picture is None else RingWeights(face)
    if not args.motion and rings is None:
        return None, None, 0
    source = open_source(args.input)
    limit = max(neutral + 1, round(args.motion_seconds * source.fps))
    total = min(limit, source.length or limit)
    progress = progress_for("fd-enroll", args.quiet)
    tracker = _Watched(FaceTracker(), None if rings is None else rings.add)
    update = (lambda n: progress.update(n, total, "learning how the face, hair and shoulders move")) \
        if progress else None
    try:
        residual, vertices = residuals(islice(source.frames(), limit), tracker, face, source.fps,
                                       args.motion_over, neutral, update)
    finally:
        if progress:
            progress.close()
    motion = learn_motion(residual, vertices, args.motion, args.motion_over) if args.motion else None
    return motion, None if rings is None else rings.weights(), len(residual)


class _Watched:
    """A tracker that also hands each frame and its landmarks to ``watch`` (None: nobody)."""

    def __init__(self, tracker, watch) -> None:
        self._tracker, self._watch = tracker, watch

    def track(self, frame_bgr: np.ndarray) -> np.ndarray | None:
        landmarks = self._tracker.track(frame_bgr)
        if self._watch is not None:
            self._watch(frame_bgr, landmarks)
        return landmarks


def _neutral_frame(source, base, wanted: int | None, seconds: float):
    """(index, BGR frame, (468, 3) landmarks in pixels, (468, 3) pose-free landmarks, (gap, degrees)).

    With ``wanted`` that frame; otherwise the most neutral frame of the first
    ``seconds`` after the face first appears.
    """
    from common.errors import InputError, NoFaceError
    from sender.calibrate import lip_gap
    from sender.pose import STABLE_LANDMARKS, fit_pose, image_to_face_axes
    from sender.tracker import FaceTracker

    tracker = FaceTracker()
    stable = list(STABLE_LANDMARKS)
    window = max(1, round(seconds * source.fps))
    best, best_cost, seen, count = None, 0.0, 0, 0
    for count, frame in enumerate(source.frames(), 1):
        index = count - 1
        if wanted is not None and index < wanted:
            continue
        landmarks = tracker.track(frame)
        if landmarks is not None:
            points = image_to_face_axes(landmarks)
            pose = fit_pose(points[stable], base.vertices[stable])
            score = (lip_gap(landmarks), float(np.linalg.norm(pose.head_rotation_vector())))
            cost = float(score[0] / GAP_UNIT + score[1] / ANGLE_UNIT)
            if best is None or cost < best_cost:
                best, best_cost = (index, frame, landmarks, pose.apply(points), score), cost
            seen += 1
        if wanted is not None:
            if best is None:
                raise NoFaceError(f"{_name(source)}: no face in frame {wanted}")
            return best
        if seen >= window:
            break
    if wanted is not None:
        raise InputError(f"--frame {wanted}: the clip has only {count} frames")
    if best is None:
        raise NoFaceError(f"{_name(source)}: no face found in any frame")
    return best


def _name(source) -> str:
    """The source's path for messages ('input' for a source without one)."""
    return str(getattr(source, "path", "input"))


if __name__ == "__main__":
    sys.exit(main())
