"""A person's face model from a video of them (``facedeform.enroll``, fd-enroll).

The mesh is the person's own landmarks in a neutral frame with the head pose
removed; the whole neutral frame is kept as the reference picture, with where
the face sits in it, and their widest open mouth beside it: the receiver then
draws the whole picture, warped by the moving face (codec/render/picture.py). When the
clip shows them talking, the model also carries their own motion basis
(sender/motion.py) and how far the hair and shoulders around the face follow
the head (sender/motion_global.RingWeights), and where the clip shows a blink, the person's own
shut eyes (:class:`ShutEyes`).

The clip is read twice: once over its first seconds to choose the neutral and
the open-mouth frames, and once more over the motion window, measured against
the model the first pass made (the model has to exist before motion can be
measured against it, and holding a minute of frames would cost hundreds of MB).
"""

from collections import deque
from dataclasses import dataclass, replace
from itertools import islice

import cv2
import numpy as np

from facedeform.codec.face_file.format import Face, decode_face, personal_face
from facedeform.codec.model.face_model import BaseFace, ReferencePicture, load_base_face, mouth_vertices, normalise
from facedeform.codec.model.head_pose import image_to_face_axes
from facedeform.codec.model.motion_basis import OVER
from facedeform.common.errors import InputError, NoFaceError
from facedeform.common.parameters import MAX_COMPONENTS
from facedeform.sender.calibrate import eye_opening, eyes_open, lip_gap
from facedeform.sender.motion import learn_motion, residuals
from facedeform.sender.motion_global import RingWeights
from facedeform.sender.pose import STABLE_LANDMARKS, Pose, fit_pose
from facedeform.sender.sources import open_source
from facedeform.sender.texture import texture_from_frame

TEXTURE_SIZE = 256  # texels a side: about 20 KB as JPEG, detail for a 512-pixel rendering
#: A frame's distance from neutral: lip gap (over eye distance) in units of GAP_UNIT plus head
#: turn in units of ANGLE_UNIT, so a 0.05 gap (lips visibly parted) weighs as 10 degrees of turn.
GAP_UNIT, ANGLE_UNIT = 0.05, 10.0
NEUTRAL_KEPT = 5  # the most neutral frames kept while the window passes (a blink lasts a few frames)
#: On the dev clips each pattern up to 12 (the most their halves can teach) lowers the error at a given rate.
MOTION_PATTERNS = 12
#: The open mouth kept for the receiver: the enrolment window's widest lip gap (over eye distance)
#: past OPEN_GAP with the head turned under MOUTH_TURN degrees, cropped with MOUTH_MARGIN pixels.
OPEN_GAP, MOUTH_TURN, MOUTH_MARGIN = 0.08, 15.0, 3
TEXTURE_SIDES = (64, 1024)
#: A blink opens again within this many seconds of shutting: how far before and after a frame ShutEyes looks.
AROUND = 0.5
#: The landmarks around the eyes that the lids do not move (the eyes' corners, the brows, the nose's
#: bridge): by them a blink's frame is laid onto the reference picture.
EYE_FRAME = (33, 133, 362, 263, 70, 63, 105, 66, 107, 336, 296, 334, 293, 300, 6, 168, 197)


@dataclass(frozen=True)
class Enrolment:
    """What enrolment made and chose: the face; the neutral frame's index, lip gap (over eye
    distance) and head turn (degrees); the motion basis's patterns (0: none) and the frames with
    a face it was learned from."""

    face: Face
    frame: int
    lip_gap: float
    head_turn: float
    patterns: int
    motion_frames: int


def enroll_face(video, frame: int | None = None, seconds: float = 2.0, motion: int = MOTION_PATTERNS,
                motion_over: str = "rest", motion_seconds: float = 60.0, picture: bool = True,
                texture_size: int = TEXTURE_SIZE, on_frame=None, budget: int | None = None) -> Enrolment:
    """The face model of the person in ``video`` (a video file, an image directory or a %d
    pattern: it is read twice, ``sender.sources.open_source``).

    frame: the neutral frame's index (None: of the first ``seconds`` after the face appears, the
    one with the mouth most closed and the head nearest frontal); motion: most patterns in the
    motion basis (0: none), learned from the first ``motion_seconds`` over ``motion_over``
    ("rest" or "paper", codec/model/motion_basis.py); picture: keep the reference picture (else only a
    texture of ``texture_size`` texels a side); on_frame(done, total): progress of the motion pass;
    budget: the file's most bytes, as far as a coarser picture can (None: 10,000, 20,000 for an HD
    picture; 0: none; ``codec.face_file.format.within_budget``).
    Caller mistakes are ValueError; a clip that cannot be read or shows no face, FdError.
    """
    if frame is not None and frame < 0:
        raise ValueError(f"frame takes an index from 0, not {frame}")
    if not 0 <= motion <= MAX_COMPONENTS:
        raise ValueError(f"motion must be 0 to {MAX_COMPONENTS}, not {motion}")
    if motion_over not in OVER:
        raise ValueError(f"motion_over must be one of {', '.join(OVER)}, not {motion_over!r}")
    if not TEXTURE_SIDES[0] <= texture_size <= TEXTURE_SIDES[1]:
        raise ValueError(f"texture_size must be {TEXTURE_SIDES[0]} to {TEXTURE_SIDES[1]}, not {texture_size}")
    if not (seconds > 0 and motion_seconds > 0):
        raise ValueError("seconds and motion_seconds must be above 0")
    base = load_base_face()
    found = first_seconds(open_source(str(video)), base, frame, seconds)
    rgb = cv2.cvtColor(found.frame, cv2.COLOR_BGR2RGB)
    texture, ref = None, None
    if picture:
        ref = reference_picture(rgb, found.landmarks, found.aligned, base, found.mouth)
    else:
        texture = texture_from_frame(rgb, found.landmarks[:, :2], base.uv, base.faces, texture_size)
    first = decode_face(personal_face(found.aligned, texture, base, picture=ref))
    basis, rings, shut, frames = _learn(video, first, rgb, found.index, motion, motion_over, motion_seconds, on_frame)
    if rings is not None and ref is not None:
        ref = replace(ref, ring_weights=rings)
    if ref is not None and shut is not None and (eyes := shut.laid_on(first, found.landmarks)) is not None:
        ref = replace(ref, shut_eyes=eyes[0], shut_eyes_at=eyes[1])
    face = Face(personal_face(found.aligned, texture, base, basis, ref, budget))
    return Enrolment(face, found.index, found.score[0], found.score[1],
                     0 if basis is None else basis.components, frames)


def reference_picture(rgb: np.ndarray, landmarks: np.ndarray, aligned: np.ndarray, base: BaseFace,
                      mouth=None) -> ReferencePicture:
    """The whole (H, W, 3) RGB frame as the reference picture, with the projection that puts the
    face model made from ``aligned`` (``personal_face`` normalises it, in ``base``'s topology) onto
    its (468, 3) landmarks; ``mouth``: (RGB frame, landmarks) of a frame with the mouth open, or None."""
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


@dataclass
class FirstSeconds:
    """The neutral frame (index, BGR frame, (468, 3) landmarks in pixels, (468, 3) pose-free
    landmarks, (lip gap, degrees of turn)) and the widest open mouth ((RGB frame, landmarks) or None)."""

    index: int
    frame: np.ndarray
    landmarks: np.ndarray
    aligned: np.ndarray
    score: tuple[float, float]
    mouth: tuple[np.ndarray, np.ndarray] | None


@dataclass
class _Closing:
    """A frame whose eyes are shut against the frames before it, waiting for them to open again."""

    opening: float
    frame: tuple[np.ndarray, np.ndarray]  # (RGB frame, landmarks)
    left: int  # frames still to see
    after: float = 0.0  # the most open the eyes were since


class ShutEyes:
    """The enrolment clip's deepest blink, from its frames in order at ``fps``: of the frames whose eyes
    are shut against the most open they were AROUND seconds before and after (calibrate.eyes_open: a
    blink closes and opens again, where a look down or a squint stays), with the head turned under
    MOUTH_TURN degrees (its pose fitted to ``face``), the least open (calibrate.eye_opening). The
    tracker brings a shut eye's lids only about half together: to 0.68 of the open gap on the bundled clip."""

    def __init__(self, face: BaseFace, fps: float) -> None:
        self._face = face
        self._span = max(1, round(AROUND * fps))  # frames
        self._before: deque[float] = deque(maxlen=self._span)  # the openings seen before
        self._pending: _Closing | None = None  # a candidate, until its eyes open again or AROUND passes
        self.opening = float("inf")
        self.frame: tuple[np.ndarray, np.ndarray] | None = None  # (RGB frame, landmarks)

    def see(self, frame_bgr: np.ndarray, landmarks: np.ndarray | None) -> None:
        """The next frame and its landmarks (None: no face seen)."""
        opening = float("nan") if landmarks is None else float(eye_opening(landmarks))
        pending = self._pending
        if pending is not None:
            pending.left -= 1
            if landmarks is not None:
                pending.after = max(pending.after, opening)
            if not eyes_open(pending.opening, pending.after):  # open again: a blink
                self.opening, self.frame, self._pending = pending.opening, pending.frame, None
            elif pending.left == 0:
                self._pending = None
        if landmarks is None:
            self._before.append(0.0)
            return
        before = max(self._before, default=0.0)
        deepest = self.opening if self._pending is None else min(self.opening, self._pending.opening)
        if opening < deepest and not eyes_open(opening, before) and _posed(landmarks, self._face)[2] < MOUTH_TURN:
            rgb = cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2RGB)
            self._pending = _Closing(opening, (rgb, landmarks), self._span)
        self._before.append(opening)

    def laid_on(self, face: BaseFace, neutral: np.ndarray) -> tuple[np.ndarray, tuple[int, int]] | None:
        """(the shut eyes in ``face``'s reference picture's pixels, cut to the eyelids' box; its top-left
        pixel), or None without a blink. The blink's frame is laid onto the picture triangle by triangle
        of the mesh, its landmarks onto the face's vertices at rest: where the receiver's mesh shuts the
        lids it squashes this back into the blink as the frame showed it, the lashes where the lids meet
        (a similarity over EYE_FRAME alone left them in the eye's middle, which the mesh squashes away).
        Past the mesh's triangles (the box's margin), the similarity from the landmarks round the eyes
        to the neutral frame's ``neutral``."""
        from facedeform.codec.render.eyelids import Eyelids
        from facedeform.codec.render.picture import SceneMesh

        if self.frame is None or face.picture is None:
            return None
        rgb, landmarks = self.frame
        frame = list(EYE_FRAME)
        matrix, _ = cv2.estimateAffinePartial2D(np.asarray(landmarks[frame, :2], np.float32),
                                                np.asarray(neutral[frame, :2], np.float32),
                                                method=cv2.LMEDS)
        if matrix is None:
            return None
        height, width = face.picture.image.shape[:2]
        rest = SceneMesh(face, face.picture).rest_pixels
        x0, y0, x1, y1 = Eyelids(face, rest, (width, height)).box
        shifted = matrix.copy()
        shifted[:, 2] -= (x0, y0)
        out = cv2.warpAffine(rgb, shifted, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        seen = np.asarray(landmarks, dtype=np.float64)[:, :2]
        for triangle in face.faces:
            corners = rest[triangle] - (x0, y0)
            lo, hi = np.floor(corners.min(axis=0)).astype(int), np.ceil(corners.max(axis=0)).astype(int) + 1
            lo, hi = np.maximum(lo, 0), np.minimum(hi, (x1 - x0, y1 - y0))
            (ax, ay), (bx, by) = corners[1] - corners[0], corners[2] - corners[0]
            if np.any(hi <= lo) or abs(ax * by - ay * bx) < 1e-3:
                continue
            back = cv2.getAffineTransform(np.asarray(corners - lo, np.float32),  # box pixels -> frame
                                          np.asarray(seen[triangle], np.float32))
            size = (int(hi[0] - lo[0]), int(hi[1] - lo[1]))
            piece = cv2.warpAffine(rgb, back, size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                   borderMode=cv2.BORDER_REPLICATE)
            inside = np.zeros(size[::-1], np.uint8)
            cv2.fillConvexPoly(inside, np.round((corners - lo) * 16).astype(np.int32), 1, cv2.LINE_8, 4)
            region = out[lo[1]:hi[1], lo[0]:hi[0]]
            region[inside > 0] = piece[inside > 0]
        return np.ascontiguousarray(out), (x0, y0)


def first_seconds(source, base: BaseFace, wanted: int | None, seconds: float) -> FirstSeconds:
    """One pass over the first ``seconds`` after the face appears (and on to frame ``wanted``):
    the neutral frame (``wanted``, else the most neutral whose eyes are open against the most open in
    the window, calibrate.eyes_open, since a reference picture of shut eyes draws every frame of the call
    with them half shut; of the NEUTRAL_KEPT most neutral) and the frame with the mouth most open
    past OPEN_GAP with the head turned under MOUTH_TURN degrees."""
    from facedeform.sender.tracker import FaceTracker

    tracker = FaceTracker()
    window = max(1, round(seconds * source.fps))
    kept: list[tuple[float, int, float, FirstSeconds]] = []  # (cost, index, eyes' opening, frame), cheapest first
    mouth, mouth_gap, seen, count, most_open = None, OPEN_GAP, 0, 0, 0.0
    for count, frame in enumerate(source.frames(), 1):
        index = count - 1
        landmarks = tracker.track(frame)
        if landmarks is not None:
            points, pose, turn = _posed(landmarks, base)
            gap = float(lip_gap(landmarks))
            in_window = seen < window
            seen += in_window
            if in_window and gap > mouth_gap and turn < MOUTH_TURN:
                mouth, mouth_gap = (cv2.cvtColor(frame, cv2.COLOR_BGR2RGB), landmarks), gap
            opening = float(eye_opening(landmarks))
            most_open = max(most_open, opening)
            cost = gap / GAP_UNIT + turn / ANGLE_UNIT
            if index == wanted or wanted is None:
                here = FirstSeconds(index, frame, landmarks, pose.apply(points), (gap, turn), None)
                kept = sorted(kept + [(cost, index, opening, here)], key=lambda k: k[:2])[:NEUTRAL_KEPT]
        elif index == wanted:
            raise NoFaceError(f"{_name(source)}: no face in frame {wanted}")
        if seen >= window and (wanted is None or index >= wanted):
            break
    if wanted is not None and count <= wanted:
        raise InputError(f"frame {wanted}: the clip has only {count} frames")
    if not kept:
        raise NoFaceError(f"{_name(source)}: no face found in any frame")
    if wanted is None:
        kept = [k for k in kept if eyes_open(k[2], most_open)] or kept
    best = kept[0][3]
    best.mouth = mouth
    return best


def _posed(landmarks: np.ndarray, face: BaseFace) -> tuple[np.ndarray, Pose, float]:
    """(``landmarks`` in face axes, the head pose fitted to them against ``face`` over the stable
    landmarks, its turn in degrees)."""
    points = image_to_face_axes(landmarks)
    stable = list(STABLE_LANDMARKS)
    pose = fit_pose(points[stable], face.vertices[stable])
    return points, pose, float(np.linalg.norm(pose.head_rotation_vector()))


def _learn(video, face: BaseFace, seen: np.ndarray, neutral: int, patterns: int, over: str, seconds: float,
           on_frame):
    """(the person's MotionBasis or None, their ring weights and ShutEyes or None, frames with a face
    seen), from one pass over the clip's first ``seconds``: the motion basis when ``patterns`` asks for
    one (sender/motion.py), the ring weights (sender/motion_global.RingWeights) and the blinks when
    ``face`` has a reference picture, each frame tracked once for all. The ring weights are measured
    on the picture as the camera gave it, ``seen`` (RGB), not as the face file codes it: on
    tpsmm_driving's crop, measured on its AV1 copy they cost the whole picture 0.09 dB more
    (docs/face_file.md)."""
    from facedeform.sender.tracker import FaceTracker

    rings = None if face.picture is None else RingWeights(replace(face, picture=replace(face.picture, image=seen)))
    if not patterns and rings is None:
        return None, None, None, 0
    source = open_source(str(video))
    shut = None if rings is None else ShutEyes(face, source.fps)
    limit = max(neutral + 1, round(seconds * source.fps))
    total = min(limit, source.length or limit)
    tracker = _Watched(FaceTracker(), () if rings is None or shut is None else (rings.add, shut.see))
    update = None if on_frame is None else (lambda n: on_frame(n, total))
    residual, vertices = residuals(islice(source.frames(), limit), tracker, face, source.fps, over, neutral, update)
    motion = learn_motion(residual, vertices, patterns, over) if patterns else None
    return motion, None if rings is None else rings.weights(), shut, len(residual)


class _Watched:
    """A tracker that also hands each frame and its landmarks to each of ``watchers``."""

    def __init__(self, tracker, watchers) -> None:
        self._tracker, self._watchers = tracker, watchers

    def track(self, frame_bgr: np.ndarray) -> np.ndarray | None:
        landmarks = self._tracker.track(frame_bgr)
        for watch in self._watchers:
            watch(frame_bgr, landmarks)
        return landmarks


def _name(source) -> str:
    """The source's path for messages ('input' for a source without one)."""
    return str(getattr(source, "path", "input"))
