"""Pinhole and orthographic cameras mapping world points to pixels.

World space is right-handed: x right, y up, z toward the viewer. Screen space
has pixel x to the right and pixel y down, with pixel (i, j) covering
[i, i+1) x [j, j+1) so its centre is at (i + 0.5, j + 0.5).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


def _vec3(value, name: str) -> tuple[float, float, float]:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"camera {name} must be 3 finite numbers, got {value!r}")
    return (float(arr[0]), float(arr[1]), float(arr[2]))


@dataclass(frozen=True)
class Camera:
    """A camera looking from ``eye`` at ``target``.

    ``kind`` is "perspective" (``fov_y_deg`` is the vertical field of view) or
    "orthographic" (``height`` is the world-space height the image spans).
    Build one with :meth:`perspective` or :meth:`orthographic`.
    """

    kind: str
    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float]
    fov_y_deg: float
    height: float
    near: float
    far: float
    _axes: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        # the axes, validated once: project() runs every frame
        object.__setattr__(self, "_axes", self._axes_of())

    @classmethod
    def perspective(cls, fov_y_deg: float, eye, target, up=(0, 1, 0),
                    near: float = 0.01, far: float = 100.0) -> Camera:
        if not 0.0 < fov_y_deg < 180.0:
            raise ValueError(f"fov_y_deg must be in (0, 180), got {fov_y_deg}")
        return cls._build("perspective", eye, target, up, float(fov_y_deg), 0.0, near, far)

    @classmethod
    def orthographic(cls, height: float, eye, target, up=(0, 1, 0),
                     near: float = 0.01, far: float = 100.0) -> Camera:
        if not height > 0.0 or not math.isfinite(height):
            raise ValueError(f"orthographic height must be positive, got {height}")
        return cls._build("orthographic", eye, target, up, 0.0, float(height), near, far)

    @classmethod
    def _build(cls, kind, eye, target, up, fov, height, near, far) -> Camera:
        cam = cls(kind, _vec3(eye, "eye"), _vec3(target, "target"), _vec3(up, "up"),
                  fov, height, float(near), float(far))
        if not 0.0 < cam.near < cam.far < math.inf:
            raise ValueError(f"need 0 < near < far < inf, got near={near} far={far}")
        return cam

    @property
    def is_perspective(self) -> bool:
        return self.kind == "perspective"

    def basis(self) -> np.ndarray:
        """(3, 3) float64 rows: camera right, up and backward (toward the viewer) axes."""
        return self._axes.copy()

    def _axes_of(self) -> np.ndarray:
        back = np.subtract(self.eye, self.target)
        norm = np.linalg.norm(back)
        if norm == 0.0:
            raise ValueError("camera eye and target coincide")
        back = back / norm
        right = np.cross(self.up, back)
        rnorm = np.linalg.norm(right)
        if rnorm < 1e-12:
            raise ValueError("camera up is parallel to the viewing direction")
        right = right / rnorm
        return np.stack([right, np.cross(back, right), back])

    def focal(self, height: int) -> float:
        """Focal length in pixels of a perspective camera for an image ``height`` pixels tall."""
        return 0.5 * height / math.tan(math.radians(self.fov_y_deg) * 0.5)

    def project(self, points: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        """Map (n, 3) world points to (n, 4) float64 screen coordinates.

        Columns: pixel x (right), pixel y (down), depth = distance along the
        viewing axis (positive in front of the camera), and 1/w: 1/depth for a
        perspective camera (screen-linear, for perspective-correct
        interpolation), 1 for an orthographic one. ``size`` is (width, height).
        """
        width, height = size
        rel = np.asarray(points, dtype=np.float64) - np.asarray(self.eye)
        view = rel @ self._axes.T
        depth = -view[:, 2]
        out = np.empty((view.shape[0], 4), dtype=np.float64)
        if self.is_perspective:
            focal = self.focal(height)
            with np.errstate(divide="ignore", invalid="ignore"):
                inv = 1.0 / depth
            out[:, 0] = 0.5 * width + focal * view[:, 0] * inv
            out[:, 1] = 0.5 * height - focal * view[:, 1] * inv
            out[:, 3] = inv
        else:
            scale = height / self.height
            out[:, 0] = 0.5 * width + scale * view[:, 0]
            out[:, 1] = 0.5 * height - scale * view[:, 1]
            out[:, 3] = 1.0
        out[:, 2] = depth
        return out
