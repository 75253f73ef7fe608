"""Face landmarks frame after frame, tracked the way MediaPipe's face mesh tracks them.

The detector runs only to find a face; after that each frame is cropped around
the previous frame's landmarks, which is cheaper than detecting and steadier,
until the landmark model says the face has gone. Unlike MediaPipe, a frame where
the face was detected is fitted twice, the second time from its own landmarks'
crop, so that it agrees with the frames after it.
"""

import numpy as np

from facedeform.sender.detector import FaceDetector
from facedeform.sender.landmarks import LandmarkModel, Roi

#: Landmarks at the outer corners of the person's right and left eye: they level the crop.
RIGHT_EYE_CORNER, LEFT_EYE_CORNER = 33, 263


class FaceTracker:
    """Follows one face (the largest when several are in view) through a video.

    ``detections`` counts the detector's runs: the first search plus every re-detection.
    """

    def __init__(self, min_detection_score: float = 0.5, min_presence: float = 0.5) -> None:
        self.min_presence = min_presence
        self._detector = FaceDetector(min_detection_score)
        self._landmarks = LandmarkModel()
        self._roi: Roi | None = None
        self.detections = 0

    def reset(self) -> None:
        """Forget the previous face: the next frame is searched from scratch."""
        self._roi = None

    def track(self, frame_bgr: np.ndarray) -> np.ndarray | None:
        """frame_bgr: (H, W, 3) uint8 BGR. Returns (468, 3) float32 landmarks in frame pixels
        (x right, y down, z at the scale of x and negative toward the camera), or None."""
        frame = np.asarray(frame_bgr, np.uint8, order="C")
        if frame.ndim != 3 or frame.shape[2] != 3:
            raise ValueError(f"expected an (H, W, 3) BGR frame, got shape {frame.shape}")
        if self._roi is not None:
            found = self._fit(frame, self._roi)
            if found is not None:
                return found
        roi = self._detect(frame)
        if roi is None or self._fit(frame, roi) is None or self._roi is None:
            return None
        # The detector's box frames the face otherwise than the landmark crops of every later frame,
        # and landmarks from it are off by 1-2 px (up to 4 at the chin, a degree of head turn): a
        # rest face taken from such a frame would bias every parameter. Fit again from their own crop.
        return self._fit(frame, self._roi)

    def _detect(self, frame: np.ndarray) -> Roi | None:
        self.detections += 1
        faces = self._detector.detect(frame)
        if not faces:
            return None
        face = max(faces, key=lambda d: d.area)
        return Roi.around(face.box, face.keypoints[0], face.keypoints[1])

    def _fit(self, frame: np.ndarray, roi: Roi) -> np.ndarray | None:
        """Landmarks inside ``roi``, remembering where to look next; None if no face is there."""
        points, presence = self._landmarks.run(frame, roi)
        if presence < self.min_presence:
            self._roi = None
            return None
        xy = points[:, :2]
        self._roi = Roi.around(np.concatenate([xy.min(axis=0), xy.max(axis=0)]),
                               xy[RIGHT_EYE_CORNER], xy[LEFT_EYE_CORNER])
        return points
