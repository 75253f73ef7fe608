"""The region map: which vertices rotate with the jaw, and how the others blend.

Paper section 3.1: a stretch region is a triangle of three feature points
(Fi, Fj, Fk); a vertex X of it is projected from one common centre O onto the
plane of that triangle, and the barycentric weights (sub-triangle areas) of the
projected point P blend the three feature vectors. Because O is shared and
neighbouring regions share an edge, the weights agree on every shared border.

Membership: a vertex belongs to the stretch region whose triangle contains P
(weights >= -tol). A vertex no triangle covers is a jaw vertex if it lies below
the plane through O and the hinge axis (the band outside the polyline
F12-F14-F4-F15-F13: chin and jaw line); otherwise it takes the nearest region
(largest smallest weight) with its weights clipped to the triangle. Inner-lip
vertices only take the lip regions on their own side of the mouth slit.

Two departures from the paper, both for the shape of an opening mouth (measured
in docs/deformation.md):
- The inner lips never take the slit's thin triangles (F9, F8, F2), (F9, F3, F8):
  seen from O the lip curve wanders in and out of them, and their weights along
  it are not monotonic, so an opening lower lip showed a saw of skin teeth.
- The lower lip's midpoint weight w of F3 is rounded to 1 - (1 - w)^2 (the
  other two weights scaled to keep the sum 1): linear blending bends the lip at
  F3 into a V, the rounded one into the U of a real lip. The map w -> 1 - (1 - w)^2
  depends on w alone, which is the same on both sides of a shared edge, so the
  motion stays continuous, and F3 itself still moves by exactly V3.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from codec.face_model import BaseFace

FEATURE_NAMES: tuple[str, ...] = tuple(f"F{i}" for i in range(1, 16))
COVER_TOL = 1e-9
#: Feature points whose blend weight is rounded (module docstring). Rounding F2 as well was
#: measured too: no better fit of real upper lips, so the upper lip keeps the paper's blend.
ROUNDED = ("F3",)


@dataclass(frozen=True, eq=False)
class RegionMap:
    """Per-vertex region data, computed once per base face.

    names: stretch region names then jaw region names; region (n,) int index into
    names; jaw (n,) bool; weights (n, 15) float64, row i blends the feature
    vectors F1..F15 for stretch vertex i (rows of jaw vertices are 0);
    triangles (r, 3) int feature indices (0 = F1) of the stretch regions;
    origin (3,) the projection centre O; covered (n,) bool, False where the
    vertex fell outside every triangle and took a neighbour's clipped weights.
    """

    names: tuple[str, ...]
    region: np.ndarray
    jaw: np.ndarray
    weights: np.ndarray
    triangles: np.ndarray
    origin: np.ndarray
    covered: np.ndarray


def feature_positions(face: BaseFace) -> np.ndarray:
    """(15, 3) positions of F1..F15."""
    return face.vertices[[face.feature_points[n] for n in FEATURE_NAMES]]


def project_weights(points: np.ndarray, tri: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """Barycentric weights (k, 3) of the central projections from origin of points (k, 3)
    onto the plane of tri (3, 3); rows are nan where the ray misses the plane in front of O.

    Weight j is the signed area of the sub-triangle opposite corner j over the
    whole area: equation (1)'s S_j / (S1 + S2 + S3).
    """
    a, b, c = tri
    normal = np.cross(b - a, c - a)
    rays = points - origin
    denom = rays @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((a - origin) @ normal) / denom
    p = origin + t[:, None] * rays
    area = normal @ normal
    w = np.stack(
        [np.cross(c - b, p - b) @ normal, np.cross(a - c, p - c) @ normal, np.cross(b - a, p - a) @ normal],
        axis=1,
    ) / area
    w[~(t > 0)] = np.nan
    return w


def build_region_map(face: BaseFace) -> RegionMap:
    """Assign every vertex of face to a stretch or jaw region (see module docstring)."""
    meta = face.meta
    fpos = feature_positions(face)
    index = {n: i for i, n in enumerate(FEATURE_NAMES)}
    stretch = list(meta["stretch_regions"].items())
    triangles = np.array([[index[p] for p in tri] for _, tri in stretch], dtype=np.int64)
    origin = np.asarray(meta["projection_centre_O"], dtype=np.float64)
    x = face.vertices
    n = len(x)

    all_w = np.stack([project_weights(x, fpos[t], origin) for t in triangles])  # (r, n, 3)
    min_w = np.nan_to_num(all_w.min(axis=2), nan=-np.inf)  # (r, n)
    inside_any = (min_w >= -COVER_TOL).any(axis=0)
    _keep_slit(min_w, triangles, meta["loops"], index)
    best = min_w.argmax(axis=0)
    covered = min_w[best, np.arange(n)] >= -COVER_TOL

    f12, f13, f4 = fpos[index["F12"]], fpos[index["F13"]], fpos[index["F4"]]
    up = np.cross(f12 - origin, f13 - origin)
    up *= -np.sign((f4 - origin) @ up)
    jaw = ~inside_any & ((x - origin) @ up < 0)

    w = np.clip(all_w[best, np.arange(n)], 0.0, None)
    w /= w.sum(axis=1, keepdims=True)
    weights = np.zeros((n, len(FEATURE_NAMES)))
    np.add.at(weights, (np.arange(n)[:, None], triangles[best]), w)
    weights[jaw] = 0.0
    for name in ROUNDED:
        _round(weights, index[name])

    names = tuple(name for name, _ in stretch) + tuple(meta["jaw_regions"]["names"])
    region = best.copy()
    region[jaw] = len(stretch) + _jaw_part(x[jaw], origin, fpos[index["F14"]], fpos[index["F15"]])
    return RegionMap(names, region, jaw, weights, triangles, origin, covered)


def _round(weights: np.ndarray, column: int) -> None:
    """Round (in place) one feature point's weights w to 1 - (1 - w)^2, scaling the row's others by
    (1 - new) / (1 - w) so each row still sums to 1."""
    w = weights[:, column].copy()
    rounded = 1.0 - (1.0 - w) ** 2
    rest = 1.0 - w
    weights *= np.divide(1.0 - rounded, rest, out=np.zeros_like(w), where=rest > 0)[:, None]
    weights[:, column] = rounded


def _keep_slit(min_w: np.ndarray, triangles: np.ndarray, loops: dict, index: dict) -> None:
    """Forbid (in place) the slit's triangles and those using the other lip's midpoint (F3 for
    upper inner-lip vertices, F2 for lower ones) to the inner lips, so the mouth opens along
    the lips, not a straight chord, and each lip moves smoothly along its length.

    The canonical mouth is open by only ~0.03 units, so geometry alone may put an
    inner-lip vertex on the wrong side of the chord F9-F8 or inside a slit triangle;
    such a vertex takes the nearest lip region, its weights clipped onto the lip's edge.
    The corners, on both loops, are left to geometry.
    """
    upper, lower = set(loops["inner_lip_upper"]), set(loops["inner_lip_lower"])
    slit = (triangles == index["F8"]).any(axis=1) & (triangles == index["F9"]).any(axis=1)
    for lip, other in ((upper - lower, "F3"), (lower - upper, "F2")):
        bad = np.flatnonzero(slit | (triangles == index[other]).any(axis=1))
        min_w[np.ix_(bad, sorted(lip))] = -np.inf


def _jaw_part(x: np.ndarray, origin: np.ndarray, f14: np.ndarray, f15: np.ndarray) -> np.ndarray:
    """0 (face-left jaw line), 1 (chin) or 2 (face-right jaw line) per jaw vertex,
    split by the vertical planes through O and F14 / F15 (display only: all rotate alike)."""
    pts = np.vstack([x, f14, f15]) - origin
    slope = pts[:, 0] / pts[:, 2]
    s, s14, s15 = slope[:-2], slope[-2], slope[-1]
    return np.where(s > s14, 0, np.where(s < s15, 2, 1))
