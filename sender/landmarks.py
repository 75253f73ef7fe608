"""The face-mesh landmark model, fed rotated square crops exactly as MediaPipe feeds it.

The model was trained on crops made a precise way (square, 1.5x the face,
eyes level, replicated borders, RGB in [0, 1]); matching that recipe is what
makes its output agree with MediaPipe's to a fraction of a pixel.
"""

from dataclasses import dataclass

import cv2
import numpy as np

from facedeform.sender.detector import load_model

INPUT_SIZE = 192
#: The crop is this much larger than the face box, on the box's longer side.
ROI_SCALE = 1.5


@dataclass(frozen=True)
class Roi:
    """A rotated square in frame pixels: ``center`` (2,), side ``size``, ``angle`` in radians
    (positive turns the crop's x axis toward the frame's y axis, i.e. clockwise on screen)."""

    center: np.ndarray
    size: float
    angle: float

    @classmethod
    def around(cls, box: np.ndarray, start: np.ndarray, end: np.ndarray) -> "Roi":
        """The crop around ``box`` (4,) xmin, ymin, xmax, ymax, turned so that the line from
        ``start`` to ``end`` (2,) (right eye to left eye) comes out horizontal."""
        box = np.asarray(box, np.float64)
        dx, dy = np.asarray(end, np.float64) - np.asarray(start, np.float64)
        return cls(center=(box[:2] + box[2:]) / 2, size=ROI_SCALE * float(np.max(box[2:] - box[:2])),
                   angle=float(np.arctan2(dy, dx)))

    def crop_to_frame(self) -> np.ndarray:
        """(2, 3) affine map from crop pixels (0..INPUT_SIZE) to frame pixels."""
        c, s = np.cos(self.angle), np.sin(self.angle)
        k = self.size / INPUT_SIZE
        linear = k * np.array([[c, -s], [s, c]])
        return np.hstack([linear, (self.center - linear @ [INPUT_SIZE / 2, INPUT_SIZE / 2])[:, None]])


class LandmarkModel:
    """468 face-mesh landmarks and a face-presence probability for one crop."""

    def __init__(self) -> None:
        self._net = load_model("face_landmark.tflite")
        self._outputs = ["conv2d_21", "conv2d_31"]

    def run(self, frame_bgr: np.ndarray, roi: Roi) -> tuple[np.ndarray, float]:
        """frame_bgr: (H, W, 3) uint8 BGR. Returns (468, 3) float32 landmarks in frame pixels
        (z at the scale of x, negative toward the camera) and the presence probability."""
        to_frame = roi.crop_to_frame()
        crop = cv2.warpAffine(frame_bgr, cv2.invertAffineTransform(to_frame), (INPUT_SIZE, INPUT_SIZE),
                              flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        self._net.setInput(cv2.dnn.blobFromImage(crop, 1 / 255, swapRB=True))
        points, logit = self._net.forward(self._outputs)
        points = points.reshape(468, 3).astype(np.float64)
        xy = points[:, :2] @ to_frame[:, :2].T + to_frame[:, 2]
        z = points[:, 2:] * (roi.size / INPUT_SIZE)
        presence = 1 / (1 + np.exp(-float(logit.ravel()[0])))
        return np.hstack([xy, z]).astype(np.float32), float(presence)
