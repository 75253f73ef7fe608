"""Measure the paper's deformation parameters on pose-free landmarks.

Every landmark is a vertex of the base face, so a parameter is read as the
displacement of its feature point from the person's rest face, in base-face
units: V2, V3, V8, V9 directly, and the jaw angle as the rotation about the
hinge axis that best explains how the chin and jaw line moved.
"""

import numpy as np
from scipy.optimize import minimize_scalar

from codec.deform import PAPER_PARAMS, Deformer
from codec.face_model import BaseFace

#: Chin and jaw-line landmarks: they move with the jaw and with little else.
JAW_LANDMARKS = (152, 148, 176, 149, 150, 377, 400, 378, 379)
#: The inner lips at the middle, for the lip gap.
UPPER_INNER_LIP, LOWER_INNER_LIP = 13, 14
THETA_RANGE = (-15.0, 45.0)  # degrees: a little closing past rest, a wide yawn


class ParameterEstimator:
    """Turns (468, 3) aligned landmarks into (13,) paper parameters, given a rest face."""

    names = PAPER_PARAMS

    def __init__(self, face: BaseFace, deformer: Deformer) -> None:
        self._base_jaw = face.vertices[list(JAW_LANDMARKS)]
        self._deformer = deformer
        self._free = [face.feature_points[f] for f in ("F2", "F3", "F8", "F9")]
        self.neutral: np.ndarray | None = None

    def set_neutral(self, aligned: np.ndarray) -> None:
        """Use (468, 3) aligned landmarks as the person's rest face."""
        self.neutral = np.array(aligned, dtype=np.float64)

    def estimate(self, aligned: np.ndarray) -> np.ndarray:
        """(468, 3) aligned landmarks -> (13,) parameters in PAPER_PARAMS order."""
        moved = np.asarray(aligned, dtype=np.float64) - self.neutral
        jaw_moved = moved[list(JAW_LANDMARKS)]

        def misfit(theta: float) -> float:
            model = self._deformer.rotate_jaw(self._base_jaw, theta) - self._base_jaw
            return float(((model - jaw_moved) ** 2).sum())

        theta = minimize_scalar(misfit, bounds=THETA_RANGE, method="bounded",
                                options={"xatol": 0.01}).x
        return np.concatenate([[theta], moved[self._free].ravel()])


def lip_gap(landmarks: np.ndarray) -> float:
    """Inner-lip gap of (468, 3) landmarks over their inter-ocular distance (a scale-free mouth opening)."""
    eyes = landmarks[[33, 133]].mean(axis=0), landmarks[[362, 263]].mean(axis=0)
    return float(np.linalg.norm(landmarks[UPPER_INNER_LIP] - landmarks[LOWER_INNER_LIP])
                 / np.linalg.norm(eyes[0] - eyes[1]))
