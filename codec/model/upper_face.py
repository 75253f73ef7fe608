"""The upper face 'the same way' (beyond the paper): brows, upper lids, cheeks, and the eyes' gaze.

The paper's upper regions use fixed points only. The ``upper_face`` section of
feature_points.json re-tiles them with new feature points F16.. (brows, eye
corners, upper lids, cheeks), blended exactly as the paper's stretch regions:
central projection from O onto the feature triangle, area weights. The
lower-face regions and their weights are left untouched, so the paper's
deformation is unchanged and the upper face adds a linear term.

Each upper-face parameter gives every new point a vector at value 1 (below);
lid points move toward their lower-lid partner ('closes_to'), so lid = 1 lays
each upper-lid landmark onto the lower lid. The mesh has no eyeball, so gaze
cannot deform it: ``EyeModel`` gives a sphere behind each eye opening and the
iris centre on it for a gaze (yaw, pitch), for the renderer to paint.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facedeform.codec.model.face_model import BaseFace
from facedeform.codec.model.regions import RegionMap, project_weights
from facedeform.common.parameters import UPPER_PARAMS

BROW_INNER = {"inner": 1.0, "mid": 0.4, "outer": 0.0}  # share of brow_inner (up) and brow_knit (medial)
GLABELLA_SHARE = 0.25  # the glabella rises by this share of each brow's raise and of brow_inner
CHEEK_DIRECTION = (0.0, 1.0, 0.25)  # AU6 lifts the cheek and pushes it slightly forward
EYE_RADIUS = 0.4  # eyeball radius over eye width (corner to corner): about 12 mm over 30 mm
IRIS_RADIUS = 0.2  # iris radius over eye width: about 6 mm over 30 mm


@dataclass(frozen=True, eq=False)
class UpperFace:
    """The upper-face extension of one base face.

    names: the new feature point names (F16..); landmarks (k,) their vertices;
    triangles (r, 3) landmark indices of the upper stretch regions (fixed paper
    points included); region (n,) index into triangles, -1 outside the upper
    face; weights (n, k) blend of the new points' vectors; vectors (p, k, 3)
    the new points' vectors per UPPER_PARAMS entry at value 1; basis (3n, p)
    = weights @ vectors, so the displacement is (basis @ values).reshape(n, 3).
    """

    names: tuple[str, ...]
    landmarks: np.ndarray
    triangles: np.ndarray
    region: np.ndarray
    weights: np.ndarray
    vectors: np.ndarray
    basis: np.ndarray


def build_upper_face(face: BaseFace, paper: RegionMap) -> UpperFace:
    """Re-tile the vertices of the paper's replaced (all-fixed) regions with the upper-face regions."""
    spec = face.meta["upper_face"]
    points = spec["feature_points"]
    names = tuple(points)
    lm = {**face.feature_points, **{n: int(p["landmark"]) for n, p in points.items()}}
    triangles = np.array([[lm[n] for n in tri] for tri in spec["stretch_regions"].values()], dtype=np.int64)
    x, origin = face.vertices, paper.origin
    replaced = [paper.names.index(n) for n in spec["replaces"]]
    idx = np.flatnonzero(np.isin(paper.region, replaced) & ~paper.jaw)

    all_w = np.stack([project_weights(x[idx], x[t], origin) for t in triangles])  # (r, k, 3)
    min_w = np.nan_to_num(all_w.min(axis=2), nan=-np.inf)
    lids = [int(p["landmark"]) for p in points.values() if p["role"] == "lid"]
    lower = np.isin(idx, [int(p["closes_to"]) for p in points.values() if p["role"] == "lid"])
    min_w[np.ix_(np.isin(triangles, lids).any(axis=1), lower)] = -np.inf  # lower lid never follows the upper
    best = min_w.argmax(axis=0)
    w = np.clip(all_w[best, np.arange(len(idx))], 0.0, None)
    w /= w.sum(axis=1, keepdims=True)

    col = {v: i for i, v in enumerate(lm[n] for n in names)}
    weights = np.zeros((len(x), len(names)))
    for corner in range(3):
        lms = triangles[best, corner]
        new = np.array([v in col for v in lms])
        weights[idx[new], [col[v] for v in lms[new]]] += w[new, corner]
    region = np.full(len(x), -1)
    region[idx] = best
    vectors = _unit_vectors(face, points)
    basis = np.einsum("nk,pkd->ndp", weights, vectors).reshape(3 * len(x), len(UPPER_PARAMS))
    landmarks = np.array([lm[n] for n in names])
    return UpperFace(names, landmarks, triangles, region, weights, vectors, basis)


def _unit_vectors(face: BaseFace, points: dict) -> np.ndarray:
    """(len(UPPER_PARAMS), k, 3) vector of each new point per upper-face parameter at value 1."""
    vec = np.zeros((len(UPPER_PARAMS), len(points), 3))
    par = {n: i for i, n in enumerate(UPPER_PARAMS)}
    x = face.vertices
    for k, p in enumerate(points.values()):
        side, role = p.get("side"), p["role"]
        medial = -np.sign(x[p["landmark"], 0])
        if role == "brow":
            vec[par[f"brow_{side[0]}_y"], k, 1] = 1.0
            vec[par["brow_inner"], k, 1] = BROW_INNER[p["part"]]
            vec[par["brow_knit"], k, 0] = medial * BROW_INNER[p["part"]]
        elif role == "glabella":
            vec[[par["brow_l_y"], par["brow_r_y"], par["brow_inner"]], k, 1] = GLABELLA_SHARE
        elif role == "lid":
            vec[par[f"lid_{side[0]}"], k] = x[p["closes_to"]] - x[p["landmark"]]
        elif role == "cheek":
            vec[par[f"cheek_{side[0]}"], k] = CHEEK_DIRECTION
    return vec


def gaze_direction(yaw_deg: float, pitch_deg: float) -> np.ndarray:
    """(3,) unit gaze in face coordinates: yaw toward the face's own left (+x), pitch up."""
    yaw, pitch = np.radians(yaw_deg), np.radians(pitch_deg)
    return np.array([np.sin(yaw) * np.cos(pitch), np.sin(pitch), np.cos(yaw) * np.cos(pitch)])


@dataclass(frozen=True)
class EyeModel:
    """Two eyeballs the mesh lacks, fitted behind its eye openings (rows: face-left eye, face-right eye).

    centres (2, 3) eyeball centres; radius the eyeball radius and iris_radius
    the iris radius, base-face units. At gaze (0, 0) the iris centre is the
    point of the sphere straight ahead, near the middle of the eye opening.
    """

    centres: np.ndarray
    radius: float
    iris_radius: float

    @classmethod
    def fit(cls, face: BaseFace) -> EyeModel:
        loops = [face.meta["loops"]["eye_left"], face.meta["loops"]["eye_right"]]
        x = face.vertices
        width = np.mean([np.linalg.norm(x[lp[0]] - x[lp[8]]) for lp in loops])  # corners: 0 and 8
        radius = EYE_RADIUS * width
        centres = np.array([x[lp].mean(axis=0) - [0.0, 0.0, radius] for lp in loops])
        return cls(centres, float(radius), float(IRIS_RADIUS * width))

    def iris_centres(self, yaw_deg: float, pitch_deg: float) -> np.ndarray:
        """(2, 3) iris centres (face coordinates, before head pose) for one gaze of both eyes."""
        return self.centres + self.radius * gaze_direction(yaw_deg, pitch_deg)

    def iris_offsets(self, yaw_deg: float, pitch_deg: float) -> np.ndarray:
        """(2, 3) move of each iris centre from its rest place (gaze 0, 0)."""
        return self.iris_centres(yaw_deg, pitch_deg) - self.iris_centres(0.0, 0.0)
