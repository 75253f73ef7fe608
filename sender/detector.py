"""BlazeFace short-range face detection, decoded the way MediaPipe decodes it.

The detector only starts (or restarts) tracking, so it favours a faithful match
of MediaPipe's boxes and eye keypoints: the tracker's first crop, and so every
landmark after it, depends on them.
"""

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from facedeform.common.errors import InputError

MODELS = Path(__file__).parent / "models"
INPUT_SIZE = 128
#: Feature-map strides of the short-range model; equal strides share one grid.
STRIDES = (8, 16, 16, 16)
NMS_IOU = 0.3


def load_model(name: str) -> cv2.dnn.Net:
    """Load a .tflite model from sender/models, on OpenCV 5.0's classic engine where it has one.

    OpenCV 5.0's new engine exposed only one output of these models; its classic engine returns all
    of them from one forward pass, and faster. OpenCV 4 has only the classic engine, and 5.1 only
    the new one, which returns both outputs again.
    """
    path = MODELS / name
    engine = getattr(cv2.dnn, "ENGINE_CLASSIC", None)
    try:
        net = cv2.dnn.readNetFromTFLite(str(path)) if engine is None else \
            cv2.dnn.readNetFromTFLite(str(path), engine=engine)
    except cv2.error:
        net = None
    if net is None or net.empty():
        raise InputError(f"{path}: face model missing or unreadable")
    return net


def ssd_anchors() -> np.ndarray:
    """(896, 2) float32 anchor centres in [0, 1]; the short-range model's anchors are all 1x1."""
    centres = []
    for stride in sorted(set(STRIDES)):
        per_cell = 2 * STRIDES.count(stride)  # each layer adds a square and an interpolated anchor
        cells = INPUT_SIZE // stride
        grid = (np.arange(cells) + 0.5) / cells
        ys, xs = np.meshgrid(grid, grid, indexing="ij")
        centres.append(np.repeat(np.stack([xs.ravel(), ys.ravel()], axis=1), per_cell, axis=0))
    return np.concatenate(centres).astype(np.float32)


@dataclass(frozen=True)
class Detection:
    """One face in frame pixels: ``box`` (4,) xmin, ymin, xmax, ymax; ``keypoints`` (6, 2)
    right eye, left eye, nose tip, mouth, right ear, left ear (the person's right and left)."""

    score: float
    box: np.ndarray
    keypoints: np.ndarray

    @property
    def area(self) -> float:
        return float((self.box[2] - self.box[0]) * (self.box[3] - self.box[1]))


class FaceDetector:
    """Finds faces in a whole frame; :meth:`detect` returns them best score first."""

    def __init__(self, min_score: float = 0.5) -> None:
        self.min_score = min_score
        self._net = load_model("face_detection_short_range.tflite")
        self._anchors = ssd_anchors()
        self._outputs = ["regressors", "classificators"]

    def detect(self, frame_bgr: np.ndarray) -> list[Detection]:
        """frame_bgr: (H, W, 3) uint8 BGR. Faces scoring at least ``min_score``, after weighted NMS."""
        h, w = frame_bgr.shape[:2]
        side = max(h, w)
        # Letterbox into a black square centred on the frame, scaled to the model input in one warp.
        scale = INPUT_SIZE / side
        to_input = np.array([[scale, 0, (side - w) / 2 * scale],
                             [0, scale, (side - h) / 2 * scale]], np.float32)
        square = cv2.warpAffine(frame_bgr, to_input, (INPUT_SIZE, INPUT_SIZE), flags=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        self._net.setInput(cv2.dnn.blobFromImage(square, 1 / 127.5, mean=(127.5, 127.5, 127.5),
                                                  swapRB=True))
        raw, logits = (o.reshape(-1, o.shape[-1]) for o in self._net.forward(self._outputs))
        scores = 1 / (1 + np.exp(-np.clip(logits[:, 0].astype(np.float64), -100, 100)))
        keep = np.flatnonzero(scores >= self.min_score)
        if keep.size == 0:
            return []
        # Offsets are in input pixels relative to the anchor centre; decode to [0, 1] of the square.
        reg = raw[keep] / INPUT_SIZE
        centre = reg[:, :2] + self._anchors[keep]
        half = reg[:, 2:4] / 2
        boxes = np.concatenate([centre - half, centre + half], axis=1)
        keypoints = reg[:, 4:16].reshape(-1, 6, 2) + self._anchors[keep, None, :]
        pad = np.array([(side - w) / 2, (side - h) / 2])
        detections = weighted_nms(scores[keep], boxes, keypoints)
        return [Detection(s, b * side - np.tile(pad, 2), k * side - pad) for s, b, k in detections]


def iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Intersection over union of (4,) ``box`` with each of (n, 4) ``boxes`` (xmin, ymin, xmax, ymax)."""
    lo = np.maximum(box[:2], boxes[:, :2])
    hi = np.minimum(box[2:], boxes[:, 2:])
    inter = np.prod(np.clip(hi - lo, 0, None), axis=1)
    union = np.prod(box[2:] - box[:2]) + np.prod(boxes[:, 2:] - boxes[:, :2], axis=1) - inter
    return inter / np.maximum(union, 1e-12)


def weighted_nms(scores: np.ndarray, boxes: np.ndarray,
                 keypoints: np.ndarray) -> Iterator[tuple[float, np.ndarray, np.ndarray]]:
    """MediaPipe's weighted NMS: each cluster of overlapping candidates becomes their
    score-weighted mean box and keypoints, which is steadier than keeping the top one.

    scores (n,), boxes (n, 4), keypoints (n, 6, 2). Yields (score, (4,) box, (6, 2) keypoints) per face, best first.
    """
    remaining = np.argsort(-scores, kind="stable")
    while remaining.size:
        overlap = iou(boxes[remaining[0]], boxes[remaining]) > NMS_IOU
        cluster = remaining[overlap]
        weights = scores[cluster] / scores[cluster].sum()
        yield (float(scores[remaining[0]]), weights @ boxes[cluster],
               np.tensordot(weights, keypoints[cluster], axes=1))
        remaining = remaining[~overlap]
