"""Frames -> landmarks -> pose -> parameters, with calibration and face loss.

The first second of video with a face is buffered to find the person's rest
face (the frame with the mouth most closed); afterwards every frame comes out
as soon as it goes in.
"""

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from codec.errors import NoFaceError
from sender.estimate import ParameterEstimator, lip_gap
from sender.pose import STABLE_LANDMARKS, Pose, fit_pose, image_to_face_axes

#: Per frame without a face, the parameters keep this fraction of their value: the face relaxes to rest.
RELAX = 0.8


@dataclass(frozen=True)
class FrameAnalysis:
    landmarks: np.ndarray | None  # (468, 3) float32 tracker output in pixels, None without a face
    pose: Pose | None
    params: np.ndarray  # (k,) float64 paper parameters then head rotation vector (degrees)


class FaceAnalyser:
    """Runs a tracker and an estimator over frames; yields one :class:`FrameAnalysis` per frame."""

    def __init__(self, tracker, estimator: ParameterEstimator, base_vertices: np.ndarray,
                 calibration_frames: int) -> None:
        self._tracker = tracker
        self._estimator = estimator
        self._stable = list(STABLE_LANDMARKS)
        self._reference = base_vertices[self._stable]
        self._calibration_frames = max(1, calibration_frames)
        self.names = estimator.names + ("rx", "ry", "rz")
        self.frames_without_face = 0

    def run(self, frames: Iterable[np.ndarray]) -> Iterator[FrameAnalysis]:
        pending: list[tuple[np.ndarray | None, Pose | None, np.ndarray | None]] = []
        previous = np.zeros(len(self.names))
        for frame in frames:
            landmarks = self._tracker.track(frame)
            pose = aligned = None
            if landmarks is not None:
                points = image_to_face_axes(landmarks)
                pose = fit_pose(points[self._stable], self._reference)
                aligned = pose.apply(points)
            else:
                self.frames_without_face += 1
            if self._estimator.neutral is None:
                pending.append((landmarks, pose, aligned))
                if sum(a is not None for *_, a in pending) < self._calibration_frames:
                    continue
                self._calibrate(pending)
                for item in pending:
                    previous = self._params(item[1], item[2], previous)
                    yield FrameAnalysis(item[0], item[1], previous)
                pending = []
                continue
            previous = self._params(pose, aligned, previous)
            yield FrameAnalysis(landmarks, pose, previous)
        if pending:
            if all(a is None for *_, a in pending):
                raise NoFaceError("no face found in any frame")
            self._calibrate(pending)
            for item in pending:
                previous = self._params(item[1], item[2], previous)
                yield FrameAnalysis(item[0], item[1], previous)

    def _calibrate(self, pending) -> None:
        faces = [(lm, a) for lm, _, a in pending if a is not None]
        rest = min(faces, key=lambda item: lip_gap(item[0]))
        self._estimator.set_neutral(rest[1])

    def _params(self, pose: Pose | None, aligned: np.ndarray | None, previous: np.ndarray) -> np.ndarray:
        if aligned is None:
            return previous * RELAX
        return np.concatenate([self._estimator.estimate(aligned), pose.head_rotation_vector()])
