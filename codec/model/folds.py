"""Which triangles of a deformed face have turned over against the rest face.

A blend of feature vectors is linear, so vectors that carry one point past its
neighbours (a lower lip sent down into the chin) turn the skin between them
inside out. The refined rule (codec/model/deform.py) uses this to keep every triangle
that faces the viewer facing its own way; tests use it to say what a fold is.
"""

from __future__ import annotations

import numpy as np

#: A triangle facing the viewer at rest (its normal within about 73 degrees of +z) also folds when
#: its winding on screen (x, y) reverses, which the normal alone can miss for thin triangles.
FACING_Z = 0.3


def normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m, 3) unnormalised normals (twice the area) of the triangles ``faces`` (m, 3)."""
    v = np.asarray(vertices, dtype=np.float64)
    a = v[faces[:, 0]]
    (bx, by, bz), (cx, cy, cz) = (v[faces[:, 1]] - a).T, (v[faces[:, 2]] - a).T
    return np.stack([by * cz - bz * cy, bz * cx - bx * cz, bx * cy - by * cx], axis=1)  # np.cross, 3x faster here


def facing_viewer(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m,) bool: the triangles ``faces`` (m, 3) of ``vertices`` that face the viewer (FACING_Z)."""
    n = normals(vertices, faces)
    return n[:, 2] > FACING_Z * np.linalg.norm(n, axis=1)


class Facing:
    """How much of each triangle still faces the way it did at rest, for one mesh's triangles.

    ``fills`` (m,) bool marks triangles that fill an opening (mouth, eyes): those may close to
    nothing (shut lips, a blink) and fold only once turned over."""

    def __init__(self, rest: np.ndarray, faces: np.ndarray, fills: np.ndarray | None = None) -> None:
        self._faces = np.asarray(faces)
        self._fills = np.zeros(len(self._faces), bool) if fills is None else np.asarray(fills, bool)
        rest_normals = normals(rest, self._faces)
        length = np.linalg.norm(rest_normals, axis=1)
        self._unit_over_area = rest_normals / (length * length)[:, None]
        self._facing = facing_viewer(rest, self._faces)
        self._rest_z = np.where(self._facing, rest_normals[:, 2], 1.0)

    def kept(self, vertices: np.ndarray) -> np.ndarray:
        """(m,) the part of each triangle's rest area that still faces its rest normal (1 at rest,
        0 edge-on, negative turned over), and for those facing the viewer at rest, at most the part
        of their screen area that keeps its winding."""
        n = normals(vertices, self._faces)
        along = np.einsum("ij,ij->i", n, self._unit_over_area)
        return np.where(self._facing, np.minimum(along, n[:, 2] / self._rest_z), along)

    def folded(self, vertices: np.ndarray, keep: float = 0.0) -> np.ndarray:
        """(m,) bool: triangles keeping no more than ``keep`` of their area facing their way; for the
        fills, turned over by more than ``keep``."""
        kept = self.kept(vertices)
        return np.where(self._fills, kept < -keep, kept <= keep)
