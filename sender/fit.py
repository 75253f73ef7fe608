"""Analysis by synthesis: the parameters whose deformed base mesh best matches the observed face.

Every landmark is a vertex of the base face, so the receiver's own model can be
fitted to all mouth and jaw landmarks at once instead of reading four feature
points. The model is linear where it can be:

- the jaw rotation R(theta) = I + sin(theta) K + (1 - cos(theta)) K^2 (Rodrigues),
  so every lower-face vertex is c0 + sin(theta) c1 + (1 - cos(theta)) c2 + B v,
  with v the 12 sent vector components and c1, c2, B fixed by the region map;
- the upper face (brows, lids, cheeks) and the richer mouth (codec/model/mouth.py)
  are fixed linear bases; the mouth's is fitted jointly with the paper's vectors;
- a person's own motion basis (codec/model/motion_basis.py) was learned from what the
  paper's fit leaves over, or from the whole motion, so it is fitted the same
  way: to the residual of the paper's fit, or of the rest face (paper parameters 0).

For a fixed theta the best v is a ridge least-squares solve; eliminating v
leaves a quadratic form in (sin, 1 - cos), so theta is a 1-D minimisation of a
trigonometric polynomial whose coefficients are two dot products per frame.
"""

import numpy as np

from facedeform.codec.model.deform import FREE, JAW_FOLLOWING, Deformer, extended_params
from facedeform.codec.model.mouth import LOWER_LIP_PARAMS
from facedeform.codec.model.regions import FEATURE_NAMES
from facedeform.common.parameters import MOUTH_PARAMS, PAPER_PARAMS, PARAMETERS, UPPER_PARAMS, slots

THETA_RANGE = PARAMETERS["theta"].limits  # degrees: a little closing past rest, a wide yawn
#: Ridge weight, relative to each unknown's own normal-equation diagonal: keeps poorly
#: observed components near rest instead of chasing tracker noise.
RIDGE = 1e-3
_GRID = np.radians(np.linspace(*THETA_RANGE, 61))
#: How much further lids close than the tracker says: its mesh brings a shut eye's lids only about half
#: their rest gap together (0.45-0.52 in liveportrait_d11's blink), and lids lowered over eyes that look
#: down, irises half covered, 0.26-0.41 (sadtalker_WDA_KatieHill).
LID_GAIN = 2.0
#: Where the tracker shuts a speaker's lids less than that, the deepest closing seen so far in the call,
#: once it is a blink's (the lids' gap under BLINK_GAP of their rest gap), is taken as shut: the
#: bundled clip's speaker blinks fully and is tracked to 0.64 of his rest gap. At most MOST_LID_GAIN.
#: (0.75 instead of 0.7 also took sadtalker_RD_Radio34's deepest look down for a blink: her eyes'
#: opening then swung 1.40 times her own, against 1.26.)
BLINK_GAP, MOST_LID_GAIN = 0.7, 3.0
#: Weights, relative to the lower lip's own normal-equation diagonal, with which the fit of a face that
#: would fold tries holding the lower lip toward the jaw's carry (ModelFit.paper).
LIP_HOLD = (0.0625, 0.25, 1.0, 4.0, 16.0, 64.0)


def _cross_matrix(axis: np.ndarray) -> np.ndarray:
    x, y, z = axis
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def _ridge_solver(b: np.ndarray, ridge: float) -> np.ndarray:
    """(p, m) matrix taking (m,) observations to the (p,) ridge least-squares solution of b (m, p)."""
    gram = b.T @ b
    return np.linalg.solve(gram + ridge * np.diag(np.diag(gram)), b.T)


class _ThetaSolver:
    """The least-squares fit of theta and the vector components v to observations d = s c1 + c c2 +
    B v (s = sin theta, c = 1 - cos theta), v eliminated (module docstring)."""

    def __init__(self, b: np.ndarray, c1: np.ndarray, c2: np.ndarray, ridge: float) -> None:
        self._solve = _ridge_solver(b, ridge)  # (p, m)
        # min_v |u - B v|^2 + ridge |v|^2 = u^T M u with M = I - B (B^T B + ridge I)^-1 B^T
        mc1 = c1 - b @ (self._solve @ c1)
        mc2 = c2 - b @ (self._solve @ c2)
        self._mc = np.stack([mc1, mc2])  # (2, m)
        self._k = np.array([[c1 @ mc1, c1 @ mc2], [c2 @ mc1, c2 @ mc2]])
        self._c1, self._c2 = c1, c2

    def fit(self, d: np.ndarray) -> np.ndarray:
        """(m,) observations -> (1 + p,) theta in degrees and v."""
        a = self._mc @ d  # (2,)
        s, c = np.sin(_GRID), 1.0 - np.cos(_GRID)
        k = self._k
        cost = -2 * (s * a[0] + c * a[1]) + s * s * k[0, 0] + 2 * s * c * k[0, 1] + c * c * k[1, 1]
        t = _GRID[np.argmin(cost)]
        lo, hi = np.radians(THETA_RANGE)
        for _ in range(3):  # Newton on the exact cost; the grid start is within half a step
            s, c, ds, dc = np.sin(t), 1.0 - np.cos(t), np.cos(t), np.sin(t)
            g = 2 * (-(ds * a[0] + dc * a[1]) + s * ds * k[0, 0] + (ds * c + s * dc) * k[0, 1] + c * dc * k[1, 1])
            h = 2 * ((s * a[0] - ds * a[1]) + (ds * ds - s * s) * k[0, 0]
                     + (2 * ds * dc + s * ds - c * s) * k[0, 1] + (dc * dc + c * ds) * k[1, 1])
            if h <= 0:
                break
            t = float(np.clip(t - g / h, lo, hi))
        v = self._solve @ (d - np.sin(t) * self._c1 - (1.0 - np.cos(t)) * self._c2)
        return np.concatenate([[np.degrees(t)], v])


class ModelFit:
    """Fits paper parameters (and, with ``upper``, the upper-face ones) to pose-free landmarks.

    ``lower`` (k,) are the landmarks the paper's deformation (and with ``mouth``
    the richer mouth) moves: mouth, cheeks below the eyes, chin and jaw line;
    ``upper_landmarks`` (u,) those the upper face moves. Targets are (468, 3) in
    base-face units: the base face plus the person's displacement from their rest face.
    """

    def __init__(self, deformer: Deformer, ridge: float = RIDGE, mouth: bool = False) -> None:
        regions = deformer.regions
        col = {n: i for i, n in enumerate(FEATURE_NAMES)}
        free = [col[n] for n in FREE]
        follow = [col[n] for n in JAW_FOLLOWING]
        w = regions.weights
        moved = regions.jaw | (np.abs(w[:, free + follow]).sum(axis=1) > 1e-9)
        self.lower = np.flatnonzero(moved | (deformer.mouth.region >= 0) if mouth else moved)
        base = np.asarray(deformer.face.vertices, dtype=np.float64)
        _, axis = deformer.hinge_axis
        k1 = _cross_matrix(axis)
        k2 = k1 @ k1
        fpos = base[[deformer.face.feature_points[n] for n in FEATURE_NAMES]]
        rel = np.where(regions.jaw[self.lower, None], base[self.lower] - deformer.jaw_pivots(base[self.lower]), 0.0)
        wf = w[self.lower][:, follow]  # (k, 3) blend of the jaw-following points
        frel = fpos[follow] - deformer.jaw_pivots(fpos[follow])
        self._c0 = base[self.lower].ravel()
        self._c1 = (rel @ k1.T + wf @ (frel @ k1.T)).ravel()
        self._c2 = (rel @ k2.T + wf @ (frel @ k2.T)).ravel()
        b = np.kron(w[self.lower][:, free], np.eye(3))  # (3k, 12): vertex displacement per vector component
        if mouth:
            rows = deformer.mouth.basis.reshape(len(base), 3, -1)[self.lower].reshape(-1, len(MOUTH_PARAMS))
            b = np.hstack([b, rows])  # (3k, 12 + len(MOUTH_PARAMS))
        self._b = b
        self._ridge = ridge
        self._theta = _ThetaSolver(b, self._c1, self._c2, ridge)
        # the lower lip's offset from where the jaw carries F3 (and the mouth's lower points): the
        # penalty rows of the refits that keep a face from folding
        f3 = FREE.index("F3")
        self._lip_columns = [3 * f3 + i for i in range(3)] + ([12 + MOUTH_PARAMS.index(n) for n in LOWER_LIP_PARAMS]
                                                              if mouth else [])
        f3rel = fpos[col["F3"]] - deformer.jaw_pivots(fpos[[col["F3"]]])[0]
        self._lip_c1 = np.r_[k1 @ f3rel, np.zeros(len(self._lip_columns) - 3)]
        self._lip_c2 = np.r_[k2 @ f3rel, np.zeros(len(self._lip_columns) - 3)]
        self._lip_scale = float(np.mean(np.sum(b[:, self._lip_columns] ** 2, axis=0)))  # their gram diagonal
        self._refits: dict[float, _ThetaSolver] = {}
        self._names = PAPER_PARAMS + (MOUTH_PARAMS if mouth else ())
        self._slots = slots(self._names)

        up = deformer.upper
        self.upper_landmarks = np.flatnonzero(np.abs(up.weights).sum(axis=1) > 1e-9)
        bu = up.basis.reshape(len(base), 3, -1)[self.upper_landmarks].reshape(-1, len(UPPER_PARAMS))
        self._upper_solve = _ridge_solver(bu, ridge)
        self._upper_basis = bu
        self._base = base
        lids = [p for p in deformer.face.meta["upper_face"]["feature_points"].values() if p["role"] == "lid"]
        #: per lid parameter, (upper-lid landmarks, the lower-lid ones each closes onto)
        self._lid_pairs = [(np.array([p["landmark"] for p in lids if p["side"] == side]),
                            np.array([p["closes_to"] for p in lids if p["side"] == side]))
                           for side in ("left", "right")]
        self._lid_rest = [float(self._gaps(base, pair).sum()) for pair in self._lid_pairs]
        self._deepest = 1.0  # the smallest tracked lid gap over its rest gap seen so far (both eyes' mean)

        self._deformer = deformer
        motion = deformer.face.motion
        if motion is not None:
            self._motion_vertices = motion.vertices
            self._motion_solve = _ridge_solver(motion.vectors.transpose(1, 2, 0).reshape(-1, motion.components), ridge)

    def paper(self, target: np.ndarray) -> np.ndarray:
        """(468, 3) target -> (13,) parameters in PAPER_PARAMS order (theta in degrees),
        followed with ``mouth`` by the (len(MOUTH_PARAMS),) mouth parameters.

        Where the best fit would fold the face under the refined rule (a lower lip sent down into
        the chin), the receiver would draw it scaled back (Deformer.unfold). The fit then also tries
        holding the lower lip toward where the jaw carries it, ever more firmly (theta and the other
        points take up what they can of the lip's motion), and sends the closest of these that folds
        nothing."""
        d = np.asarray(target, dtype=np.float64)[self.lower].ravel() - self._c0
        params = self._theta.fit(d)
        if not self._deformer.would_fold(self._extended(params)):
            return params
        candidates = [self._deformer.unfold(self._extended(params))[self._slots]]
        for weight in LIP_HOLD:
            held = self._held(weight).fit(np.r_[d, np.zeros(len(self._lip_columns))])
            if not self._deformer.would_fold(self._extended(held)):
                candidates.append(held)
        return min(candidates, key=lambda p: float(np.sum((d - (self.lower_mesh(p).ravel() - self._c0)) ** 2)))

    def _extended(self, params: np.ndarray) -> np.ndarray:
        return extended_params(self._names, params)

    def _held(self, weight: float) -> _ThetaSolver:
        """The fit with penalty rows sqrt(weight) (carry(theta) - v) on the lower lip (cached)."""
        if weight not in self._refits:
            rows = np.zeros((len(self._lip_columns), self._b.shape[1]))
            rows[np.arange(len(rows)), self._lip_columns] = 1.0
            root = np.sqrt(weight * self._lip_scale)
            self._refits[weight] = _ThetaSolver(np.vstack([self._b, root * rows]),
                                                np.r_[self._c1, -root * self._lip_c1],
                                                np.r_[self._c2, -root * self._lip_c2], self._ridge)
        return self._refits[weight]

    def upper(self, target: np.ndarray) -> np.ndarray:
        """(468, 3) target -> (len(UPPER_PARAMS),) brow, lid and cheek parameters."""
        d = np.asarray(target, dtype=np.float64)[self.upper_landmarks] - self._base[self.upper_landmarks]
        return self._upper_solve @ d.ravel()

    def lids(self, target: np.ndarray, names: tuple[str, ...], values: np.ndarray) -> np.ndarray:
        """(2,) lid_l, lid_r: how much further the lids of the (468, 3) target are closed than the
        expression fitted so far (``values`` of ``names``) draws them, so that a blink the rest of
        the layout cannot show (a face's own basis from a clip without one) is still drawn.

        Measured as the lids' gaps, not fitted to every vertex the lid model moves: lid 1 lays
        each upper-lid landmark on its lower-lid partner, so the value is the gap still to close
        over the gap at rest (summed over each eye's seven pairs). A least-squares fit over the
        lid region gave two thirds of that in the dev clips' blinks, which then looked half open.
        The tracker's closing is taken LID_GAIN times, or as many times as shuts the deepest closing
        seen in the call, once that is a blink's (BLINK_GAP): on the bundled clip the eyes' opening
        then swings 0.93 times as far as the speaker's instead of 0.36 (benchmarks/bench_expression.py)."""
        drawn = self._deformer.blend(extended_params(names, values))
        target = np.asarray(target, dtype=np.float64)
        gaps = [self._gaps(target, pair).sum() / rest for pair, rest in zip(self._lid_pairs, self._lid_rest)]
        self._deepest = min(self._deepest, float(np.mean(gaps)))
        gain = LID_GAIN if self._deepest >= BLINK_GAP else min(MOST_LID_GAIN, max(LID_GAIN, 1 / (1 - self._deepest)))
        lids = []
        for pair, rest, gap in zip(self._lid_pairs, self._lid_rest, gaps):
            seen = max(0.0, rest * (1.0 - gain * (1.0 - gap)))  # the gap, as it is
            lids.append((self._gaps(drawn, pair).sum() - seen) / rest)
        return np.array(lids)

    @staticmethod
    def _gaps(vertices: np.ndarray, pair: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        return np.linalg.norm(vertices[pair[0]] - vertices[pair[1]], axis=1)

    def motion(self, target: np.ndarray, paper: np.ndarray) -> np.ndarray:
        """(468, 3) target and its (13,) paper fit (zeros for a basis over the rest face) -> the face's
        motion-basis coefficients (c,)."""
        v = self._motion_vertices
        left = np.asarray(target, dtype=np.float64)[v] - self._deformer.deform(paper[:13])[v]
        return self._motion_solve @ left.ravel()

    def lower_mesh(self, params: np.ndarray) -> np.ndarray:
        """(k, 3) model positions of ``lower`` for the parameters :meth:`paper` returns."""
        t = np.radians(params[0])
        m = self._c0 + np.sin(t) * self._c1 + (1.0 - np.cos(t)) * self._c2 + self._b @ params[1:]
        return m.reshape(-1, 3)

