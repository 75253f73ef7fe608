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
(largest smallest weight) with its weights clipped to the triangle.

Two rules (``RULES``), chosen per Deformer and named in the stream header so
that sender and receiver blend alike:

- "paper": equations (1) and (2) exactly, nothing else; every vertex takes the
  triangle its projection falls in (the nearest one, clipped, where it falls in
  none: only fixed-point regions at the forehead corners).
- "refined" (the default): three departures, all for the shape of an opening
  mouth (measured in docs/deformation.md):
  * The inner lips never take the slit's thin triangles (F9, F8, F2), (F9, F3, F8):
    seen from O the lip curve wanders in and out of them, and their weights along
    it are not monotonic, so an opening lower lip showed a saw of skin teeth.
  * The lower lip's body follows F3 more than a linear blend: F3's weight w is
    rounded to w + w (1 - w) s, where s rises smoothly from 0 on the inner lip
    (F4's weight 0) to 1 where F4's weight reaches ROUND_SPAN, the other weights
    scaled to keep the sum 1. A rounding of the inner lip itself (1 - (1 - w)^2,
    the rule until 2026-11-24) folded the lip corners over when the jaw opened
    past 20 degrees. The new weight depends on w and F4's weight alone, which
    agree on both sides of every border a lower-lip region shares (F4's weight is
    0 on the edge F3-F8 shared with the slit, F3's on the edge F4-F8 shared with
    the jowl), so the motion stays continuous, and F3 still moves by exactly V3.
  * A speaker's own mesh (a face file's: the shipped mesh's topology and feature
    points) takes each vertex's region, and whether it is the jaw's, from the
    shipped mesh, and its weights in that region from its own geometry. Fitted
    to a closed mouth, a speaker's lower lip near the corners sits so high that
    its outer vertices fell in the upper lip's regions (F1, F2) while the inner
    lip's stayed in the lower's, and an opening mouth turned the triangles
    between them over (the fold guard then drew the mouth scaled back).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from facedeform.codec.model.face_model import BaseFace, load_base_face
from facedeform.common.errors import InputError

FEATURE_NAMES: tuple[str, ...] = tuple(f"F{i}" for i in range(1, 16))
COVER_TOL = 1e-9
#: Deformation rules (module docstring); the stream header names the one the sender fitted with.
RULES = ("paper", "refined")
DEFAULT_RULE = "refined"
#: F4's weight at which the refined rule rounds F3's weight fully (module docstring): with 0.2 the
#: dev clips' fit is as close as with the earlier rounding and a jaw opened to 30 degrees folds no
#: triangle; smaller spans fold more often once the sent vectors join in, larger ones fit less well.
ROUND_SPAN = 0.2


@dataclass(frozen=True, eq=False)
class RegionMap:
    """Per-vertex region data, computed once per base face.

    names: stretch region names then jaw region names; region (n,) int index into
    names; jaw (n,) bool; weights (n, 15) float64, row i blends the feature
    vectors F1..F15 for stretch vertex i (rows of jaw vertices are 0);
    triangles (r, 3) int feature indices (0 = F1) of the stretch regions;
    origin (3,) the projection centre O; covered (n,) bool, False where the
    vertex fell outside every triangle and took a neighbour's clipped weights;
    rule: the rule (RULES) the weights follow.
    """

    names: tuple[str, ...]
    region: np.ndarray
    jaw: np.ndarray
    weights: np.ndarray
    triangles: np.ndarray
    origin: np.ndarray
    covered: np.ndarray
    rule: str


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


def check_rule(rule: str) -> str:
    """``rule`` if it is one of RULES; InputError otherwise."""
    if rule not in RULES:
        raise InputError(f"unknown deformation rule {rule!r}: choose one of {', '.join(RULES)}")
    return rule


def build_region_map(face: BaseFace, rule: str = DEFAULT_RULE) -> RegionMap:
    """Assign every vertex of face to a stretch or jaw region by ``rule`` (see module docstring)."""
    check_rule(rule)
    shipped = load_base_face()
    same = face.faces.shape == shipped.faces.shape and bool(np.array_equal(face.faces, shipped.faces)) \
        and face.meta == shipped.meta
    return _region_map(face, rule, _shipped_map() if rule == "refined" and same else None)


@cache
def _shipped_map() -> RegionMap:
    """The shipped mesh's map by the refined rule, whose membership a speaker's own mesh takes."""
    return _region_map(load_base_face(), "refined", None)


def _region_map(face: BaseFace, rule: str, like: RegionMap | None) -> RegionMap:
    """:func:`build_region_map`, with each vertex's membership (region, jaw) taken from ``like``
    where given."""
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
    if rule == "refined":
        _keep_slit(min_w, triangles, meta["loops"], index)
    best = min_w.argmax(axis=0)
    covered = min_w[best, np.arange(n)] >= -COVER_TOL

    f12, f13, f4 = fpos[index["F12"]], fpos[index["F13"]], fpos[index["F4"]]
    up = np.cross(f12 - origin, f13 - origin)
    up *= -np.sign((f4 - origin) @ up)
    jaw = ~inside_any & ((x - origin) @ up < 0)
    if like is not None:
        jaw, covered = like.jaw.copy(), like.covered.copy()
        best = np.where(jaw, best, like.region)

    w = np.nan_to_num(np.clip(all_w[best, np.arange(n)], 0.0, None))
    total = w.sum(axis=1, keepdims=True)
    w = np.divide(w, total, out=np.full_like(w, 1 / 3), where=total > 0)
    weights = np.zeros((n, len(FEATURE_NAMES)))
    np.add.at(weights, (np.arange(n)[:, None], triangles[best]), w)
    weights[jaw] = 0.0
    if rule == "refined":
        round_lower_lip(weights)

    names = tuple(name for name, _ in stretch) + tuple(meta["jaw_regions"]["names"])
    region = best.copy()
    region[jaw] = len(stretch) + _jaw_part(x[jaw], origin, fpos[index["F14"]], fpos[index["F15"]])
    return RegionMap(names, region, jaw, weights, triangles, origin, covered, rule)


def round_lower_lip(weights: np.ndarray) -> None:
    """The refined rule's rounding (module docstring), in place, on (k, 15) rows of blend weights."""
    f3, f4 = FEATURE_NAMES.index("F3"), FEATURE_NAMES.index("F4")
    w = weights[:, f3].copy()
    t = np.minimum(weights[:, f4] / ROUND_SPAN, 1.0)
    rounded = w + w * (1.0 - w) * t * t * (3.0 - 2.0 * t)
    rest = 1.0 - w
    weights *= np.divide(1.0 - rounded, rest, out=np.zeros_like(w), where=rest > 0)[:, None]
    weights[:, f3] = rounded


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
