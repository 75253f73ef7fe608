"""A richer mouth and jaw in the paper's formalism (beyond the paper).

The paper moves the lips by four points (F2, F3, F8, F9), so lip thickness,
the lips' shape between centre and corner and protrusion of the outer lip
cannot be shown, nor a jaw shifted sideways. Here six more free points (the
inner lips' half-way points on each side, upper and lower, and the outer lips'
mid-points) get sent 3-D vectors, blended exactly as the paper's: a finer
tiling of the lower face into triangles of feature points (paper points and the
new ones; Delaunay in the central projection from O), area weights of each
vertex's projection. Paper points carry no vector here, so this is an additive
linear term that vanishes on the tiling's rim (made of paper points only): with
zero mouth parameters the deformation is exactly the paper's. The mouth slit
is kept as in codec/model/regions.py: an upper inner-lip vertex never blends a
lower-lip point, and the reverse.

``jaw_x, jaw_y, jaw_z`` translate the mandible (sideways; and down and forward,
which with theta places the hinge where the person's is rather than at the
mesh's rim): jaw vertices and the jaw-following points F4, F14, F15 move by
that vector, blended by the paper's weights.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay

from facedeform.codec.model.face_model import BaseFace
from facedeform.codec.model.regions import COVER_TOL, FEATURE_NAMES, RegionMap, project_weights
from facedeform.common.parameters import MOUTH_PARAMS, MOUTH_POINTS

#: The new free points' landmarks, in the registry's order (common/parameters.MOUTH_POINTS names them).
MOUTH_LANDMARKS = dict(zip(MOUTH_POINTS, (311, 81, 402, 178, 0, 17), strict=True))
UPPER_SIDE = ("F2", "lip_ul", "lip_ur", "lip_uo")
LOWER_SIDE = ("F3", "lip_ll", "lip_lr", "lip_lo")
TILING_POINTS = ("F1", "F2", "F3", "F4", "F5", "F6", "F8", "F9", "F10", "F11", "F12", "F13", "F14", "F15")
#: The lower lip's new points' parameters, which the refined rule's fold guard holds back first.
LOWER_LIP_PARAMS: tuple[str, ...] = tuple(f"{p}_{a}" for p in LOWER_SIDE[1:] for a in "xyz")


@dataclass(frozen=True, eq=False)
class MouthModel:
    """triangles (r, 3) landmark indices of the finer tiling; region (n,) index into triangles,
    -1 where the mouth model does not act; weights (n, k) blend of the k new points' vectors;
    basis (3n, len(MOUTH_PARAMS)): the displacement is (basis @ values).reshape(n, 3)."""

    triangles: np.ndarray
    region: np.ndarray
    weights: np.ndarray
    basis: np.ndarray


def _tiling(face: BaseFace, origin: np.ndarray) -> np.ndarray:
    """(r, 3) landmark triangles: Delaunay of the paper's lower points and the new ones as seen from O."""
    lm = [face.feature_points[n] for n in TILING_POINTS] + list(MOUTH_LANDMARKS.values())
    rays = face.vertices[lm] - origin
    seen = rays[:, :2] / rays[:, 2:]  # central projection onto a plane z = const
    return np.asarray(lm)[Delaunay(seen).simplices]


def build_mouth(face: BaseFace, paper: RegionMap) -> MouthModel:
    """Tile the lower face (stretch vertices outside the upper face) with the new points."""
    x, origin = face.vertices, paper.origin
    triangles = _tiling(face, origin)
    replaced = [paper.names.index(n) for n in face.meta["upper_face"]["replaces"]]
    idx = np.flatnonzero(~paper.jaw & ~np.isin(paper.region, replaced))
    all_w = np.stack([project_weights(x[idx], x[t], origin) for t in triangles])  # (r, m, 3)
    min_w = np.nan_to_num(all_w.min(axis=2), nan=-np.inf)
    loops = face.meta["loops"]
    upper, lower = set(loops["inner_lip_upper"]), set(loops["inner_lip_lower"])
    lm = {**face.feature_points, **MOUTH_LANDMARKS}
    for lip, other in ((upper - lower, LOWER_SIDE), (lower - upper, UPPER_SIDE)):
        bad = np.isin(triangles, [lm[n] for n in other]).any(axis=1)
        min_w[np.ix_(bad, np.isin(idx, sorted(lip)))] = -np.inf
    best = min_w.argmax(axis=0)
    # vertices outside the tiling stay put; the inner lips always blend (the slit may uncover them)
    keep = (min_w[best, np.arange(len(idx))] >= -COVER_TOL) | np.isin(idx, sorted(upper | lower))
    idx, best = idx[keep], best[keep]
    w = np.clip(all_w[best, np.flatnonzero(keep)], 0.0, None)
    w /= w.sum(axis=1, keepdims=True)

    col = {v: i for i, v in enumerate(MOUTH_LANDMARKS.values())}
    weights = np.zeros((len(x), len(col)))
    for corner in range(3):
        lms = triangles[best, corner]
        new = np.isin(lms, list(col))
        weights[idx[new], [col[v] for v in lms[new]]] += w[new, corner]
    region = np.full(len(x), -1)
    region[idx] = best

    basis = np.zeros((len(x), 3, len(MOUTH_PARAMS)))
    for k in range(len(col)):
        for a in range(3):
            basis[:, a, 3 * k + a] = weights[:, k]
    fcol = [FEATURE_NAMES.index(n) for n in ("F4", "F14", "F15")]
    jaw = paper.weights[:, fcol].sum(axis=1) + paper.jaw  # (n,) how far each vertex follows the mandible
    for a in range(3):
        basis[:, a, 3 * len(col) + a] = jaw
    return MouthModel(triangles, region, weights, basis.reshape(3 * len(x), len(MOUTH_PARAMS)))
