"""The head's placement refined against the frame's pixels: analysis by synthesis of the pose.

The landmark fit (sender/pose.py) places the model's face where the tracker's stable landmarks say;
drawn, that face still sits a degree or a few pixels off the frame's, and the whole picture pays
for it over the face and the rings around it. Here the sender draws the model's picture as the
receiver will (the receiver's own view, at a working size), aligns it to the frame by OpenCV's ECC
(a rotation and a shift) over the head and what surrounds it, the mouth's opening left out (it is
the expression's, not the pose's), and moves the head's placement by what the alignment found.
On the dev clips' 256x256 crops at fd-send's defaults the whole picture gained 0.33-0.90 dB
(0.57 on average), at 4 kbit/s 0.01-0.85 (0.28), at the same rate (docs/picture.md). Each frame's
alignment starts from the last one's, so a few iterations suffice (15: the same dB as 40 from none).
"""

import math

import cv2
import numpy as np

from facedeform.codec.model.face_model import BaseFace, mouth_vertices
from facedeform.codec.render.picture import Placement, frame_placement, relative_pose
from facedeform.common.parameters import POSE_PARAMS
from facedeform.protocol.header import Header

#: The working picture: the picture shrunk a whole number of times (the frame then shrinks fast) so that
#: the face is about this many pixels tall, which the alignment needs whatever the picture's size. On
#: the dev crops (faces 130-160 pixels tall, shrunk twice) the same dB as at their full size (-0.01;
#: 56 pixels, some shrunk three times, -0.03), the sender at 67 frames/s instead of 51 (87 without the
#: alignment, liveportrait_d11).
FACE_PIXELS = 70
#: The region aligned: the landmarks' hull grown this many times about its centre (the head, hair, ears
#: and the nearest rings: 1.0, the face alone, gained 0.16 dB on average and lost 0.26 on a turning
#: head whose rings then dragged the wall; 1.4 gained 0.50, 1.8 0.57, 2.4 0.55), less the mouth's
#: opening grown MOUTH_GROW times.
FACE_GROW, MOUTH_GROW = 1.8, 1.6
#: The largest correction taken, in picture sides (the picture's centre moved) and degrees: more is
#: an alignment that went astray. 0.08 and 8 rather than 0.04 and 4 (2026-12-02): in a lively lean
#: (liveportrait_d12) the landmarks place the head further off than that, and the tighter bound threw
#: the whole correction away: d12 +0.07 dB at fd-send's defaults, +0.16 at 10 kbit/s, -0.03 at 4; the
#: other dev clips within 0.02 dB (liveportrait_d3 +0.02); 0.16 and 16 gave d12 0.01 dB more.
#: (An affine alignment reduced to a similarity, to follow the head's size too, lost 0.57 dB against
#: this rotation and shift.)
MOST_SHIFT, MOST_TURN = 0.08, 8.0
#: Pictures with a larger side above this are aligned every other frame, the frame between moved by the
#: last alignment: at 1920x1080 an alignment costs the sender about 5 ms (docs/picture.md).
HELD_ABOVE = 512
ITERATIONS, EPSILON, SMOOTHING = 15, 1e-4, 5  # ECC's stopping rule and its Gaussian (pixels)


def refines(face: BaseFace, names: tuple[str, ...]) -> bool:
    """Whether a stream of ``names`` for ``face`` has a pose to refine: a reference picture, whose
    layouts carry the head's place and size (sender/analysis.picture_names)."""
    return face.picture is not None and all(n in names for n in POSE_PARAMS)


class PixelPose:
    """Refines the head pose of a stream with ``header`` for ``face`` (see :func:`refines`)."""

    def __init__(self, face: BaseFace, header: Header) -> None:
        from facedeform.receiver.face_view import PictureView

        if face.picture is None or not refines(face, header.names):
            raise ValueError("the pose is refined in pixels only against a reference picture")
        height, width = face.picture.image.shape[:2]
        shrink = _shrink(width, height, Placement.from_matrix(face.picture.projection).scale / FACE_PIXELS)
        self.size = (max(16, width // shrink), max(16, height // shrink))
        self._zoom = np.array(self.size) / (width, height)
        self._view = PictureView(header, face, self.size)
        self._pose = [header.names.index(n) for n in POSE_PARAMS]
        self._mouth = mouth_vertices(face)
        self._reference, self._pivot = self._view.placing
        self._last = np.eye(2, 3, dtype=np.float32)  # the last frame's alignment, where the next one starts
        self._every = 1 if max(width, height) <= HELD_ABOVE else 2
        self._held: np.ndarray | None = None  # the last correction, lifted (see _moved)
        self._count = 0

    def refine(self, params: np.ndarray, frame_bgr: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
        """``params`` with the head pose moved so that the drawn face meets ``frame_bgr``'s (any size;
        ``landmarks``: its tracked (468, 3) pixels), or as they are if the alignment fails."""
        if self._count % self._every == 0:
            self._held = self._correction(params, frame_bgr, landmarks)
        self._count += 1
        return params if self._held is None else self._moved(params, self._held)

    def _correction(self, params: np.ndarray, frame_bgr: np.ndarray, landmarks: np.ndarray) -> np.ndarray | None:
        """(3, 4) map of picture pixels (x, y down, depth) that moves the face drawn for ``params``
        onto ``frame_bgr``'s; None if the alignment fails."""
        width, height = self.size
        frame = cv2.resize(cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2GRAY), self.size, interpolation=cv2.INTER_AREA)
        model = cv2.cvtColor(self._view.model_picture(params), cv2.COLOR_RGB2GRAY)
        points = np.asarray(landmarks, dtype=np.float64)[:, :2] * (width / frame_bgr.shape[1])
        mask = np.zeros((height, width), np.uint8)
        cv2.fillConvexPoly(mask, _hull(points, FACE_GROW), 255)
        cv2.fillConvexPoly(mask, _hull(points[self._mouth], MOUTH_GROW), 0)
        try:
            _, warp = cv2.findTransformECC(frame, model, self._last.copy(), cv2.MOTION_EUCLIDEAN,
                                           (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, ITERATIONS, EPSILON),
                                           mask, SMOOTHING)
        except cv2.error:  # no convergence, or nothing to align
            self._last = np.eye(2, 3, dtype=np.float32)
            return None
        correction = cv2.invertAffineTransform(warp).astype(np.float64)  # the drawn face's pixels to the frame's
        centre = np.array([width, height]) / 2.0
        moved = correction[:, :2] @ centre + correction[:, 2] - centre
        turn = np.degrees(np.arctan2(correction[1, 0], correction[0, 0]))
        if not (np.all(np.isfinite(correction)) and abs(turn) <= MOST_TURN
                and np.linalg.norm(moved) <= MOST_SHIFT * max(width, height)):
            self._last = np.eye(2, 3, dtype=np.float32)
            return None
        self._last = np.asarray(warp, dtype=np.float32)
        lifted = np.eye(3, 4)  # the correction in the picture's pixels, depth kept
        lifted[:2, :2], lifted[:2, 3] = correction[:, :2], correction[:, 2] / self._zoom
        return lifted

    def _moved(self, params: np.ndarray, lifted: np.ndarray) -> np.ndarray:
        """``params`` with the head placed as ``lifted`` moves the drawn face."""
        placement = frame_placement(self._reference, params[self._pose], self._pivot).matrix()
        matrix = lifted[:, :3] @ placement
        matrix[:, 3] += lifted[:, 3]
        try:
            placed = Placement.from_matrix(matrix)
        except ValueError:  # not a similarity (the correction's rounding): the pose as it was
            return params
        out = params.copy()
        out[self._pose] = relative_pose(self._reference, placed, self._pivot)
        return out


def _shrink(width: int, height: int, wanted: float) -> int:
    """The whole number of times to shrink a ``width`` x ``height`` picture, near ``wanted``: the
    nearest (by ratio) within 2/3 to 3/2 of it that divides both sides, where one does, since OpenCV
    averages a whole number of pixels far faster than a fraction of one (at 1920x1080 a frame
    shrunk 8 times took 0.6 ms, 7 times, which leaves 1920 a fraction over, 3.8 ms)."""
    nearest = max(1, round(wanted))
    exact = [s for s in range(max(1, math.ceil(wanted * 2 / 3)), math.floor(wanted * 3 / 2) + 1)
             if width % s == 0 and height % s == 0]
    return min(exact, key=lambda s: abs(math.log(s / wanted)), default=nearest)


def _hull(points: np.ndarray, grow: float) -> np.ndarray:
    centre = points.mean(axis=0)
    return cv2.convexHull(np.round(centre + grow * (points - centre)).astype(np.int32))
