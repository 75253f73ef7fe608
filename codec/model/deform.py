"""The paper's deformation (section 3.1): jaw rotation plus feature-point stretching.

Per frame the sender gives theta (degrees) and the vectors V2, V3, V8, V9:
1. the jaw-following points F4, F14, F15 rotate by theta about the hinge axis
   F12-F13; their displacements are V4, V14, V15;
2. jaw-region vertices rotate rigidly by the same rotation (by the refined rule,
   each about a pivot lowered below the axis with its depth, so that the chin goes
   down rather than back: :meth:`Deformer.jaw_pivots`);
3. a stretch-region vertex X moves by V = (S1*Vi + S2*Vj + S3*Vk) / (S1+S2+S3),
   the projection weights of X on its feature triangle: X' = X + V.
Fixed points (F1, F5, F6, F7, F10, F11, F12, F13) have V = 0. Everything that
does not depend on the parameters is precomputed, so deform() is a few numpy ops.

deform_extended() adds the upper face (codec/model/upper_face.py: brows, lids,
cheeks; gaze is for the renderer), the richer mouth and jaw (codec/model/mouth.py),
the person's own motion basis when their face model has one
(codec/model/motion_basis.py) and then a rigid head pose, with the parameters of
EXTENDED_PARAMS.

The refined rule (codec/model/regions.py) also guards against folds. A linear blend
turns skin inside out once a vector carries a point past its neighbours (a
lower lip sent down into the chin, which F4 only the jaw moves); the paper's
rule draws that as sent. The refined rule draws instead anchor + s (sent -
anchor) with the largest s (bisection) that leaves every skin triangle below
the upper face that faces the viewer at rest facing its own way (codec/model/folds.py),
the anchor being the first of these that folds nothing: the sent face with its lower
lip where the jaw carries it; the jaw alone; the face at rest below the eyes. Brows,
lids and cheeks are drawn as sent. It changes no face that does not fold. The sender
fits around it (sender/fit.py), so that it rarely acts on what fd-send sends.

Triangles edge-on at rest are not guarded: the slivers in the mouth's corners turn
over as the lips stretch and press, in the speakers' own tracked faces too (9 and 20 %
of the frames of two dev clips), and a speaker's motion basis fitted to them turned
them over in 49 and 36 %. Each time the guard drew the whole mouth scaled back, for a
sliver nobody sees: sadtalker_RD_Radio34's drawn mouth opening correlated 0.89 with
the speaker's, unguarded 0.94 (README, expression table).
"""

from __future__ import annotations

import numpy as np

from facedeform.codec.model.face_model import BaseFace
from facedeform.codec.model.folds import Facing, facing_viewer
from facedeform.codec.model.head_pose import head_pivot, rotation_from_vector, rotation_matrix
from facedeform.codec.model.mouth import LOWER_LIP_PARAMS, MouthModel, build_mouth
from facedeform.codec.model.regions import DEFAULT_RULE, FEATURE_NAMES, RegionMap, build_region_map, feature_positions
from facedeform.codec.model.upper_face import EyeModel, UpperFace, build_upper_face
from facedeform.common.parameters import (
    BASIS_PARAMS,
    EXTENDED_PARAMS,
    GAZE_PARAMS,
    MAX_COMPONENTS,
    MOUTH_PARAMS,
    PAPER_PARAMS,
    POSE_PARAMS,
    ROTATION_PARAMS,
    UPPER_PARAMS,
    slots,
    span,
)

FREE = ("F2", "F3", "F8", "F9")  # sent, in PAPER_PARAMS order
JAW_FOLLOWING = ("F4", "F14", "F15")
#: The refined rule's fold guard (module docstring) keeps this part of the rest area of every skin
#: triangle that faces the viewer facing its own way, so that none is drawn edge-on either; the mouth's
#: and eyes' fills may close.
KEEP_FACING = 0.05
#: Bisection steps of the guard: what it keeps of the motion is within 2^-12 of the most that folds nothing.
FOLD_STEPS = 12
#: By the refined rule, how far below the hinge axis (base-face units, the face 1 high) the chin turns
#: about: a jaw point's pivot is lowered in proportion to its depth below the axis, so that the jaw's
#: motion stays affine (its border with the stretched skin exact) and the rim's points stay still.
HINGE_DROP = 0.357
_UPPER, _GAZE, _MOUTH, _BASIS = (span(g) for g in (UPPER_PARAMS, GAZE_PARAMS, MOUTH_PARAMS, BASIS_PARAMS))
_ROT, _SHIFT = span(ROTATION_PARAMS), span(POSE_PARAMS[3:])
#: The slots that shape the lower face, which the fold guard scales: the paper's, the mouth's, the motion basis.
_LOWER = np.r_[span(PAPER_PARAMS), _MOUTH, _BASIS]


def extended_params(names, params: np.ndarray) -> np.ndarray:
    """(..., len(EXTENDED_PARAMS)) float64: ``params`` (..., k) of the layout ``names`` in their
    EXTENDED_PARAMS slots, zero elsewhere (the form :meth:`Deformer.deform_extended` takes)."""
    params = np.asarray(params, dtype=np.float64)
    full = np.zeros(params.shape[:-1] + (len(EXTENDED_PARAMS),))
    full[..., slots(names)] = params
    return full


class Deformer:
    """Deforms one base face by a rule of codec.model.regions.RULES ("paper": equations (1) and (2)
    exactly; "refined", the default: the project's mouth slit, rounded lower lip and fold guard);
    build once, call deform() per frame. InputError for an unknown rule."""

    def __init__(self, face: BaseFace, rule: str = DEFAULT_RULE) -> None:
        self.face = face
        self.rule = rule
        self.regions: RegionMap = build_region_map(face, rule)
        fpos = feature_positions(face)
        col = {n: i for i, n in enumerate(FEATURE_NAMES)}
        f12, f13 = fpos[col["F12"]], fpos[col["F13"]]
        axis = (f12 - f13) / np.linalg.norm(f12 - f13)
        origin = 0.5 * (f12 + f13)
        chin = fpos[col["F4"]] - origin
        if (rotation_matrix(axis, 1.0) @ chin)[1] > chin[1]:  # positive theta must lower the chin
            axis = -axis
        self._origin, self._axis = origin, axis
        down = np.array([0.0, -1.0, 0.0]) - axis[1] * axis  # the face's down, across the axis
        down /= np.linalg.norm(down)
        #: per unit of its depth below the axis (down), how far a jaw point's pivot lies below the axis
        self._pivot_drop = (HINGE_DROP if rule == "refined" else 0.0) * down / float(down @ chin)
        self._down = down
        self._col = col
        self._w = np.ascontiguousarray(self.regions.weights)  # (n, 15)
        self._fpos = fpos
        self._fpivots = self.jaw_pivots(fpos)  # each feature point's, for the jaw-following ones
        self._jaw_idx = np.flatnonzero(self.regions.jaw)
        self._jaw_pivots = self.jaw_pivots(face.vertices[self._jaw_idx])
        self._jaw_rel = face.vertices[self._jaw_idx] - self._jaw_pivots
        self._base = np.asarray(face.vertices, dtype=np.float64)
        self._free = [col[n] for n in FREE]
        self._follow = [col[n] for n in JAW_FOLLOWING]
        self.upper: UpperFace = build_upper_face(face, self.regions)
        self.eyes = EyeModel.fit(face)
        self.mouth: MouthModel = build_mouth(face, self.regions)
        n = len(self._base)
        self._motion = face.motion.matrix(n) if face.motion is not None else np.zeros((3 * n, MAX_COMPONENTS))
        self._pivot = head_pivot(self._base)
        # the upper face's own blink folds stay its own; edge-on slivers are not guarded (module docstring)
        lower = ~(self.upper.region >= 0)[face.faces].any(axis=1) & facing_viewer(self._base, face.faces)
        fills = face.mouth_faces | face.eye_faces
        self._facing = Facing(self._base, face.faces[lower], fills[lower]) if rule == "refined" else None
        self._lower_lip = [_MOUTH.start + MOUTH_PARAMS.index(n) for n in LOWER_LIP_PARAMS]

    @property
    def hinge_axis(self) -> tuple[np.ndarray, np.ndarray]:
        """(origin (3,), unit direction (3,)) of the jaw axis through F12 and F13,
        oriented so that positive theta opens the mouth (the chin moves down)."""
        return self._origin.copy(), self._axis.copy()

    def jaw_pivots(self, points: np.ndarray) -> np.ndarray:
        """(k, 3) the point each of ``points`` (k, 3) turns about with the jaw: on the hinge axis by the
        paper's rule; by the refined rule lowered in proportion to the point's depth below the axis,
        to HINGE_DROP below it at the chin (F4)."""
        points = np.asarray(points, dtype=np.float64)
        return self._origin + np.outer((points - self._origin) @ self._down, self._pivot_drop)

    def rotate_jaw(self, points: np.ndarray, theta_deg: float) -> np.ndarray:
        """(k, 3) points turned by theta_deg with the jaw (about :meth:`jaw_pivots`)."""
        rot = rotation_matrix(self._axis, theta_deg)
        pivots = self.jaw_pivots(points)
        return (np.asarray(points, dtype=np.float64) - pivots) @ rot.T + pivots

    def feature_vectors(self, params: np.ndarray, f3_with_jaw: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(15, 3) displacement vectors V1..V15 and the (3, 3) jaw rotation for params (13,).

        Fixed points get 0, the free points their sent vectors, the jaw-following
        points (and F3 when f3_with_jaw) their displacement under the jaw rotation.
        """
        p = np.asarray(params, dtype=np.float64)
        if p.shape != (len(PAPER_PARAMS),):
            raise ValueError(f"params must have shape ({len(PAPER_PARAMS)},), got {p.shape}")
        if not np.isfinite(p).all():
            raise ValueError("params must be finite")
        rot = rotation_matrix(self._axis, p[0])
        vec = np.zeros((len(FEATURE_NAMES), 3))
        vec[self._free] = p[1:].reshape(4, 3)
        follow = self._follow + ([self._col["F3"]] if f3_with_jaw else [])
        pts, pivots = self._fpos[follow], self._fpivots[follow]
        vec[follow] = (pts - pivots) @ rot.T + pivots - pts
        return vec, rot

    def deform(self, params: np.ndarray, f3_with_jaw: bool = False) -> np.ndarray:
        """(468, 3) float64 deformed vertices from params (13,) in PAPER_PARAMS order.

        f3_with_jaw: F3 rotates with the jaw (paper Fig. 7) and v3x..v3z are ignored.
        """
        p = np.asarray(params, dtype=np.float64)
        if p.shape != (len(PAPER_PARAMS),):
            raise ValueError(f"params must have shape ({len(PAPER_PARAMS)},), got {p.shape}")
        return self._unfolded(np.r_[p, np.zeros(len(EXTENDED_PARAMS) - len(PAPER_PARAMS))], f3_with_jaw)

    def deform_extended(self, params: np.ndarray, f3_with_jaw: bool = False) -> np.ndarray:
        """(468, 3) float64 vertices from params (len(EXTENDED_PARAMS),): the paper's deformation,
        plus the upper face, the mouth and the motion basis (precomputed linear terms), then the head
        pose. Gaze moves no vertex; basis coefficients past the face's own patterns move none either."""
        p = self._extended(params)
        rot, shift = self._pose(p)
        return (self._unfolded(p, f3_with_jaw) - self._pivot) @ rot.T + self._pivot + shift

    def _unfolded(self, p: np.ndarray, f3_with_jaw: bool) -> np.ndarray:
        out = self.blend(p, f3_with_jaw)
        if self._folds(out):
            out = self.blend(self._scaled_back(p, f3_with_jaw), f3_with_jaw)
        return out

    def unfold(self, params: np.ndarray, f3_with_jaw: bool = False) -> np.ndarray:
        """(len(EXTENDED_PARAMS),) the parameters the rule draws for params: themselves, unless the
        refined rule's fold guard (module docstring) scales them back."""
        p = self._extended(params)
        return self._scaled_back(p, f3_with_jaw) if self.would_fold(p, f3_with_jaw) else p

    def _scaled_back(self, p: np.ndarray, f3_with_jaw: bool) -> np.ndarray:
        """The fold guard's parameters for p, whose blend folds."""
        carry = self.feature_vectors(np.r_[p[0], np.zeros(12)], True)[0][self._col["F3"]]
        lip = p.copy()  # the lower lip where the jaw carries it, the rest as sent
        lip[4:7] = carry
        lip[self._lower_lip] = 0.0
        jaw = p.copy()  # the jaw alone
        jaw[_LOWER] = 0.0
        jaw[0], jaw[4:7] = p[0], carry
        rest = p.copy()
        rest[_LOWER] = 0.0
        anchor = next((a for a in (lip, jaw) if not self._folds(self.blend(a, f3_with_jaw))), rest)
        lo, hi = 0.0, 1.0
        for _ in range(FOLD_STEPS):
            mid = 0.5 * (lo + hi)
            if self._folds(self.blend(anchor + mid * (p - anchor), f3_with_jaw)):
                hi = mid
            else:
                lo = mid
        return anchor + lo * (p - anchor)

    def would_fold(self, params: np.ndarray, f3_with_jaw: bool = False) -> bool:
        """Whether the refined rule's fold guard acts on params (len(EXTENDED_PARAMS),): the sender
        fits again rather than let it (sender/fit.py). Never under the paper's rule, which draws folds."""
        return self._folds(self.blend(self._extended(params), f3_with_jaw))

    def blend(self, p: np.ndarray, f3_with_jaw: bool = False) -> np.ndarray:
        """(468, 3) vertices from params (len(EXTENDED_PARAMS),) before the fold guard and the head pose:
        equations (1) and (2) with the rule's weights, the jaw band rotated, plus the linear terms."""
        vec, rot = self.feature_vectors(p[: len(PAPER_PARAMS)], f3_with_jaw)
        out = self._base + self._w @ vec
        out[self._jaw_idx] = self._jaw_rel @ rot.T + self._jaw_pivots
        out += (self.upper.basis @ p[_UPPER] + self.mouth.basis @ p[_MOUTH] + self._motion @ p[_BASIS]).reshape(-1, 3)
        return out

    def _folds(self, vertices: np.ndarray) -> bool:
        return self._facing is not None and bool(self._facing.folded(vertices, KEEP_FACING).any())

    def iris(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(2, 3) iris centres and (2, 3) unit gaze directions (rows: face-left, face-right eye)
        after the head pose, for params (len(EXTENDED_PARAMS),)."""
        p = self._extended(params)
        rot, shift = self._pose(p)
        centres = (self.eyes.iris_centres(*p[_GAZE]) - self._pivot) @ rot.T + self._pivot + shift
        return centres, (centres - ((self.eyes.centres - self._pivot) @ rot.T + self._pivot + shift)) / self.eyes.radius

    @staticmethod
    def _extended(params: np.ndarray) -> np.ndarray:
        p = np.asarray(params, dtype=np.float64)
        if p.shape != (len(EXTENDED_PARAMS),):
            raise ValueError(f"params must have shape ({len(EXTENDED_PARAMS)},), got {p.shape}")
        if not np.isfinite(p).all():
            raise ValueError("params must be finite")
        return p

    @staticmethod
    def _pose(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(3, 3) head rotation (rotation vector rx, ry, rz in degrees) and (3,) translation."""
        return rotation_from_vector(p[_ROT]), p[_SHIFT]


def _preset(theta: float, v2=(0, 0, 0), v3=(0, 0, 0), v8=(0, 0, 0), v9=(0, 0, 0)) -> np.ndarray:
    return np.array([theta, *v2, *v3, *v8, *v9], dtype=np.float64)


PRESETS: dict[str, tuple[np.ndarray, bool]] = {
    "neutral": (_preset(0.0), False),
    # Fig. 7: jaw opened 10 degrees, F3 rotated with the jaw, corners tilted.
    "fig7": (_preset(10.0, v8=(0, -0.02, 0), v9=(0, 0.02, 0)), True),
    # Fig. 8: lips parted, corners drawn in and back (a rounded mouth).
    "fig8": (
        _preset(0.0, v2=(0, 0.04, 0), v3=(0, -0.04, 0), v8=(-0.07, 0, -0.07), v9=(0.07, 0, -0.07)),
        False,
    ),
    # Fig. 9: corners pulled outward, up and forward (a smile).
    "fig9": (_preset(0.0, v8=(0.04, 0.04, 0.04), v9=(-0.04, 0.04, 0.04)), False),
}
