"""Head pose: a similarity fit of stable landmarks to the base face.

The fit removes head motion before expression parameters are measured: what
remains of a landmark's motion is the face's own deformation.
"""

from dataclasses import dataclass

import numpy as np

from facedeform.codec.model.head_pose import rotation_vector
from facedeform.codec.render.picture import Placement

#: Landmarks that barely move with expression: forehead, nose bridge and tip, eye
#: corners, temples and upper cheekbones. Jaw-line, lip and lid landmarks stay out.
STABLE_LANDMARKS = (1, 4, 5, 6, 8, 9, 10, 33, 54, 67, 109, 117, 119, 121, 127, 129, 133, 143, 151,
                    168, 195, 197, 198, 263, 284, 297, 338, 346, 348, 350, 356, 358, 362, 372, 420)


@dataclass(frozen=True)
class Pose:
    """``aligned = scale * observed @ rotation.T + translation`` maps a frame onto the base face.

    ``rotation`` (3, 3) is the camera-to-face rotation; its transpose is the head's
    orientation as the camera sees it.
    """

    rotation: np.ndarray
    translation: np.ndarray
    scale: float

    def apply(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) observed points -> (n, 3) points in base-face units and orientation."""
        return self.scale * points @ self.rotation.T + self.translation

    def head_rotation_vector(self) -> np.ndarray:
        """(3,) head rotation as seen by the camera: axis times angle, in degrees."""
        return rotation_vector(self.rotation.T)

    def placement(self, factor: float = 1.0) -> Placement:
        """The inverse map, base face to the frame's face axes (codec/render/picture.py's picture axes), in a
        frame ``factor`` times as large."""
        scale = factor / self.scale
        return Placement(scale, self.rotation.T, -scale * self.rotation.T @ self.translation)


def fit_pose(observed: np.ndarray, reference: np.ndarray, weights: np.ndarray | None = None) -> Pose:
    """Weighted Umeyama similarity fit of (n, 3) ``observed`` onto (n, 3) ``reference``."""
    w = np.ones(len(observed)) if weights is None else np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    mu_o = w @ observed
    mu_r = w @ reference
    o = observed - mu_o
    r = reference - mu_r
    cov = (r * w[:, None]).T @ o
    u, sing, vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(u @ vt))
    fix = np.array([1.0, 1.0, d])
    rotation = (u * fix) @ vt
    scale = float((sing * fix).sum() / (w @ (o * o).sum(axis=1)))
    return Pose(rotation, mu_r - scale * rotation @ mu_o, scale)
