"""Frames -> landmarks -> pose -> parameters, with calibration, smoothing and face loss.

Frames are buffered until the rest face is known (the first second with a
face, or up to the ``neutral`` frame); afterwards every frame comes out as soon
as it goes in. Smoothing (One Euro) is applied either to the pose-free
landmarks before the fit or to the parameters after it (``Smoothing.stage``).
With a face model that has a reference picture, the head pose is measured
against that picture instead of the rest frame, translation and scale included
(codec/render/picture.py), whatever the layout, and the whole frame's motion against
it and the body's comes last (GLOBAL_PARAMS, BODY_PARAMS, sender/motion_global.py).
"""

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from facedeform.codec.model.deform import Deformer
from facedeform.codec.model.face_model import BaseFace
from facedeform.codec.model.head_pose import head_pivot, image_to_face_axes
from facedeform.codec.model.regions import DEFAULT_RULE
from facedeform.codec.render.picture import VIEW_DISTANCE, Placement, relative_pose
from facedeform.common.errors import InputError, NoFaceError
from facedeform.common.parameters import BODY_PARAMS, GLOBAL_PARAMS, LAYOUTS, LID_PARAMS, PAPER_PARAMS, POSE_PARAMS
from facedeform.common.stages import Tracker
from facedeform.protocol.quantise import VECTOR_STEP, steps_for
from facedeform.sender.calibrate import RestFace, choose_rest, fapu_ratios
from facedeform.sender.fit import ModelFit
from facedeform.sender.motion_global import GlobalMotion
from facedeform.sender.pose import STABLE_LANDMARKS, Pose, fit_pose
from facedeform.sender.smoothing import OneEuroFilter

#: Per frame without a face, the parameters keep this fraction of their value: the face relaxes to rest.
RELAX = 0.8
#: Layouts by name: the fixed ones (common/parameters.LAYOUTS); "personal": the coefficients of the face model's own
#: motion basis (their names depend on the face), after the paper's 13 when the basis refines
#: them, and head rotation; "auto": the closest the face allows (``resolve_layout``).
LAYOUT_NAMES = (*LAYOUTS, "personal", "auto")


def resolve_layout(layout: str, face: BaseFace) -> str:
    """``layout``, or for "auto" "personal" when ``face`` has a motion basis and "mouth" when not:
    from level 2 on, each is closer to the tracked mouth on every dev clip than the paper's set at
    any level (README, fidelity tables); the paper's set stays available by name."""
    if layout != "auto":
        return layout
    return "mouth" if face.motion is None else "personal"


def layout_names(layout: str, face: BaseFace) -> tuple[str, ...]:
    """The parameter names of ``layout`` (not "auto") for ``face``; InputError if the face cannot carry it."""
    if layout != "personal":
        return LAYOUTS[layout]
    if face.motion is None:
        raise InputError("--params personal needs a face model with a motion basis: "
                         "fd-enroll CLIP -o me.fdface, then fd-send --face me.fdface")
    paper = PAPER_PARAMS if face.motion.over == "paper" else ()
    return paper + face.motion.names + LID_PARAMS + POSE_PARAMS[:3]


def picture_names(names: tuple[str, ...], face: BaseFace, moving: bool = True, body: bool = False
                  ) -> tuple[str, ...]:
    """``names`` with, when ``face`` has a reference picture, the head's translation and scale (the
    receiver places the head in it), if ``moving`` (the picture has a background to measure
    it on) the whole frame's motion against it, and if ``body`` (it has a body to measure on) the
    body's own shift, last."""
    if face.picture is None:
        return names
    return names + (() if "tx" in names else POSE_PARAMS[3:]) + (GLOBAL_PARAMS if moving else ()) + (
        BODY_PARAMS if body else ())


@dataclass(frozen=True)
class Smoothing:
    """One Euro settings; ``strength`` divides both the cutoff and the speed gain (0: off).

    stage "landmarks" filters the pose-free landmarks and the pose before the
    fit; "params" filters the fitted parameters. The encoder's dead zone
    (protocol.quantise.hold_or_round) keeps jitter below a quantiser step off the
    wire; the filter is for the rest. Defaults, measured (README): a still face
    under camera noise of 5 grey levels changes the receiver's picture in 11 %
    of frames (80 % unfiltered), and talking faces keep most of their motion
    (held-out mouth error 0.23 against 0.16 unfiltered and 0.32 with the
    earlier speed gain of 0.05).
    """

    strength: float = 1.0
    stage: str = "landmarks"
    min_cutoff: float = 1.0
    beta: float = 0.3

    def filter(self, rate: float, scale) -> OneEuroFilter | None:
        if self.strength <= 0:
            return None
        return OneEuroFilter(rate, scale, self.min_cutoff / self.strength, self.beta / self.strength)


@dataclass(frozen=True)
class FrameAnalysis:
    landmarks: np.ndarray | None  # (468, 3) float32 tracker output in pixels, None without a face
    pose: Pose | None
    params: np.ndarray  # (k,) float64 in the analyser's ``names`` order
    target: np.ndarray | None = None  # (468, 3) observed pose-free face in base-face units (RestFace.target)
    frame: np.ndarray | None = None  # the (H, W, 3) uint8 BGR frame itself, for the picture layer


class FaceAnalyser:
    """Runs a tracker and the model fit over frames; yields one :class:`FrameAnalysis` per frame.

    layout: "paper" (the paper's 13 and head rotation), "full" (plus brows, lids, cheeks and head
    translation), "mouth" (the paper's 13, the richer mouth and jaw of codec/model/mouth.py, the lids,
    head rotation), "personal" (the paper's 13 when the face's own motion basis refines them, the
    basis, the lids, head rotation) or "auto" (``resolve_layout``); the lids of "mouth" and
    "personal" take what the rest leaves over at them (``ModelFit.lids``); calibration_frames: how
    many frames with a face to choose the rest face from; neutral: a frame index to use instead;
    rule: the deformation rule (codec.model.regions.RULES) the receiver will use, as the stream header
    names it.
    """

    def __init__(self, tracker: Tracker, face: BaseFace, fps: float, layout: str = "auto",
                 calibration_frames: int = 25, neutral: int | None = None,
                 smoothing: Smoothing = Smoothing(), rule: str = DEFAULT_RULE) -> None:
        layout = resolve_layout(layout, face)
        self._tracker = tracker
        self._face = face
        self._base = np.asarray(face.vertices, dtype=np.float64)
        self.fit = ModelFit(Deformer(face, rule), mouth=layout == "mouth")
        self._stable = list(STABLE_LANDMARKS)
        self._reference = self._base[self._stable]
        self._pivot = head_pivot(self._base)
        self._calibration_frames = max(1, calibration_frames)
        self._neutral = neutral
        self._global = None if face.picture is None else GlobalMotion(face.picture, self._base)
        if self._global is not None and not (self._global.usable or self._global.body):
            self._global = None
        moving, body = (False, False) if self._global is None else (self._global.usable, self._global.body)
        self.names = picture_names(layout_names(layout, face), face, moving, body)
        self._picture = None if face.picture is None else Placement.from_matrix(face.picture.projection)
        self._picture_width = 0 if face.picture is None else face.picture.image.shape[1]
        self._factor = 1.0  # the picture's width over the frames'
        self._upper = layout == "full"
        self._lids = not self._upper and "lid_l" in self.names
        #: The eyes' rims skip the landmark filter: a blink lasts 3-8 frames, and the filter took half of a
        #: 3-frame one away; the lids' own dead zone (a twentieth of a blink) keeps their jitter off the wire.
        self._lid_rims = sorted(face.meta["loops"]["eye_left"] + face.meta["loops"]["eye_right"])
        self._personal = layout == "personal"
        self._paper = self.names[:len(PAPER_PARAMS)] == PAPER_PARAMS
        self._translate = "tx" in self.names
        self.rest: RestFace | None = None
        self._rest_pose: Pose | None = None
        steps = steps_for(self.names)
        on_landmarks = smoothing.stage == "landmarks"
        self._landmark_filter = smoothing.filter(fps, VECTOR_STEP) if on_landmarks else None
        self._pose_filter = smoothing.filter(fps, steps_for(self._pose_names())) if on_landmarks else None
        self._param_filter = None if on_landmarks else smoothing.filter(fps, steps)
        self.frames_without_face = 0

    @property
    def _calibrated(self) -> tuple[RestFace, Pose]:
        """The rest face and its pose, once :meth:`_calibrate` has chosen them."""
        if self.rest is None or self._rest_pose is None:
            raise RuntimeError("the rest frame is not chosen yet")
        return self.rest, self._rest_pose

    def _pose_names(self) -> tuple[str, ...]:
        return POSE_PARAMS if self._translate else POSE_PARAMS[:3]

    def run(self, frames: Iterable[np.ndarray]) -> Iterator[FrameAnalysis]:
        pending: list[tuple[np.ndarray | None, Pose | None, np.ndarray | None, np.ndarray, np.ndarray]] = []
        previous = np.zeros(len(self.names))
        for index, frame in enumerate(frames):
            if self._picture_width:
                self._factor = self._picture_width / frame.shape[1]
            landmarks = self._tracker.track(frame)
            pose = aligned = None
            if landmarks is not None:
                pose, aligned = self._align(landmarks)
            else:
                self.frames_without_face += 1
            still = np.zeros(0) if self._global is None else self._global.measure(frame, landmarks)
            if self.rest is None:
                pending.append((landmarks, pose, aligned, still, frame))
                if not self._ready(pending, index):
                    continue
                self._calibrate(pending)
                for item in pending:
                    previous, target = self._params(item[1], item[2], item[3], previous)
                    yield FrameAnalysis(item[0], item[1], previous, target, item[4])
                pending = []
                continue
            previous, target = self._params(pose, aligned, still, previous)
            yield FrameAnalysis(landmarks, pose, previous, target, frame)
        if pending:
            if all(item[2] is None for item in pending):
                raise NoFaceError("no face found in any frame")
            self._calibrate(pending)
            for item in pending:
                previous, target = self._params(item[1], item[2], item[3], previous)
                yield FrameAnalysis(item[0], item[1], previous, target, item[4])

    def _align(self, landmarks: np.ndarray) -> tuple[Pose, np.ndarray]:
        points = image_to_face_axes(landmarks)
        pose = fit_pose(points[self._stable], self._reference)
        return pose, pose.apply(points)

    def _ready(self, pending: list, index: int) -> bool:
        if self._neutral is not None:
            return index >= self._neutral
        return sum(item[2] is not None for item in pending) >= self._calibration_frames

    def _calibrate(self, pending: list) -> None:
        candidates = [(i, lm, a) for i, (lm, _, a, _, _) in enumerate(pending) if a is not None]
        if not candidates:
            raise NoFaceError("no face found in any frame")
        index = choose_rest(candidates, self._neutral)
        landmarks, pose, aligned, _, _ = pending[index]
        self.rest = RestFace(aligned, fapu_ratios(aligned, self._face), index)
        self._rest_pose = pose

    def _params(self, pose: Pose | None, aligned: np.ndarray | None, still: np.ndarray,
                previous: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """(k,) parameters and the (468, 3) unsmoothed target they were fitted to (None without a
        face); ``still``: the frame's global and body motion (empty without a reference picture), which
        comes last and is measured with or without a face."""
        filters = (self._landmark_filter, self._pose_filter, self._param_filter)
        if aligned is None or pose is None:
            for f in filters:
                if f is not None:
                    f.reset()
            relaxed = previous * RELAX
            relaxed[len(relaxed) - len(still):] = still
            return relaxed, None
        observed = target = self._calibrated[0].target(aligned, self._base)
        head = self._head(pose)
        if self._landmark_filter is not None and self._pose_filter is not None:
            target = self._landmark_filter(target)
            target[self._lid_rims] = observed[self._lid_rims]
            head = self._pose_filter(head)
        paper = self.fit.paper(target) if self._paper else np.zeros(len(PAPER_PARAMS))
        parts = [paper] if self._paper else []
        if self._upper:
            parts.append(self.fit.upper(target))
        if self._personal:
            parts.append(self.fit.motion(target, paper))
        if self._lids:
            parts.append(self.fit.lids(target, self.names[:sum(map(len, parts))], np.concatenate(parts)))
        params = np.concatenate(parts + [head, still])
        if self._param_filter is not None:
            params = self._param_filter(params)
        return params, observed

    def _head(self, pose: Pose) -> np.ndarray:
        """Head rotation vector (degrees) as the camera sees it and, in the full layout, the
        translation (base-face units) of the receiver's head pivot since the rest frame; with a
        reference picture, rotation, translation and scale relative to the picture's (frames of
        another size than the picture's scaled to it)."""
        if self._picture is not None:
            return relative_pose(self._picture, pose.placement(self._factor), self._pivot)
        rotation = pose.head_rotation_vector()
        if not self._translate:
            return rotation
        rest = self._calibrated[1]
        seen = (self._pivot - pose.translation) @ pose.rotation / pose.scale  # pivot in camera axes
        seen_rest = (self._pivot - rest.translation) @ rest.rotation / rest.scale
        shift = rest.scale * (seen - seen_rest)
        shift[2] = VIEW_DISTANCE * (1.0 - pose.scale / rest.scale)  # nearer: larger in the image
        return np.concatenate([rotation, shift])
