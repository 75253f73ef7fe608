"""A person's own motion basis: a few displacement patterns of their face.

The paper's deformation (and any physical model) misses part of how a real face
moves. From an enrolment clip the sender learns (sender/motion.py, over every
vertex), by a singular value decomposition, the few displacement patterns
(pose-free, base-face units) that explain most of either what the paper's fit
leaves over (``over="paper"``: the patterns refine the paper's 13 parameters)
or the whole motion from the rest face (``over="rest"``: the patterns replace
them, fewer numbers for the same fidelity on the dev clips). The patterns are
shared once inside the face model file (codec/face_file/format.py); each frame then
carries a coefficient per pattern (``basis_0``, ``basis_1``, ...), added to the
deformed mesh like any other linear term.

Each pattern is scaled so that a coefficient of 1 moves its most-moved vertex
by exactly 1 base-face unit: the coefficients then share the quantiser step
of the feature vectors, with the same bound on the vertex error.

A face file stores each pattern in whole steps, as finely as its coefficients need
(``steps``): a pattern whose coefficients stay small is drawn just as well from
coarser numbers, which take fewer bytes.
"""

from dataclasses import dataclass

import numpy as np

from facedeform.common.errors import InputError
from facedeform.common.parameters import BASIS_PARAMS, MAX_COMPONENTS

OVER = ("rest", "paper")  # what the patterns are displacements from
#: The most steps a face file gives a pattern's unit move (a vertex coordinate in a signed byte).
MOST_STEPS = 127
#: Steps per unit of the largest coefficient the enrolment clip gave a pattern: at that coefficient a vertex
#: is then off by at most 1 / (2 REACH_STEPS) of the face's height, a quarter of a coefficient's own rounding
#: at the default level (steps of 1/250). A call may go well past the enrolment clip's largest coefficient,
#: and the rounding of a pattern in few steps then turns the lips' small triangles over: 512 (1.1-1.5 KB
#: less a face, the whole picture within 0.02 dB) had the fold guard draw liveportrait_d3's mouth scaled
#: back in most frames, its tracked opening swinging 0.34 times the speaker's (1.15 at 1024).
REACH_STEPS = 1024
LEAST_STEPS = 4


@dataclass(frozen=True)
class MotionBasis:
    """``vertices`` (k,) the landmark indices it moves; ``vectors`` (m, k, 3) float64 displacement
    of each of them per unit coefficient, for m (1..MAX_COMPONENTS) patterns; ``over``: one of OVER;
    ``steps``: (m,) how many steps a face file gives each pattern's unit move (LEAST_STEPS..MOST_STEPS;
    None: MOST_STEPS each)."""

    vertices: np.ndarray
    vectors: np.ndarray
    over: str = "rest"
    steps: np.ndarray | None = None

    def __post_init__(self) -> None:
        m, k = len(self.vectors), len(self.vertices)
        if not 1 <= m <= MAX_COMPONENTS or self.vectors.shape != (m, k, 3):
            raise InputError(f"a motion basis needs 1-{MAX_COMPONENTS} patterns of (k, 3), got {self.vectors.shape}")
        if self.over not in OVER:
            raise InputError(f"a motion basis is over one of {', '.join(OVER)}, not {self.over!r}")
        if self.steps is not None and (np.shape(self.steps) != (m,) or not np.all(
                (np.asarray(self.steps) >= 1) & (np.asarray(self.steps) <= MOST_STEPS))):
            raise InputError(f"a motion basis's steps are 1-{MOST_STEPS} for each of its {m} patterns")

    @property
    def components(self) -> int:
        return len(self.vectors)

    @property
    def names(self) -> tuple[str, ...]:
        return BASIS_PARAMS[:self.components]

    def matrix(self, n_vertices: int) -> np.ndarray:
        """(3 n_vertices, MAX_COMPONENTS) displacement of every vertex coordinate per coefficient
        (zero columns past ``components``), the form the Deformer adds with its other linear terms."""
        out = np.zeros((n_vertices, 3, MAX_COMPONENTS))
        out[self.vertices, :, :self.components] = self.vectors.transpose(1, 2, 0)
        return out.reshape(-1, MAX_COMPONENTS)


def learn_basis(residuals: np.ndarray, vertices: np.ndarray, components: int, over: str = "rest") -> MotionBasis:
    """The ``components`` patterns that best explain ``residuals`` (n, k, 3) of the landmarks
    ``vertices`` (k,) in the least-squares sense (uncentred: coefficients 0 are what the
    residuals are ``over``).

    Signs are fixed so that each pattern's most-moved vertex moves towards +y or, failing that, +x,
    so that learning twice from the same data gives the same file.
    """
    r = np.asarray(residuals, dtype=np.float64)
    if r.ndim != 3 or r.shape[1:] != (len(vertices), 3):
        raise ValueError(f"residuals must be (n, {len(vertices)}, 3), got {r.shape}")
    if not 1 <= components <= min(MAX_COMPONENTS, len(r)):
        raise InputError(f"a motion basis of {components} patterns needs at least {components} frames "
                         f"(have {len(r)}) and at most {MAX_COMPONENTS} patterns")
    u, s, vt = np.linalg.svd(r.reshape(len(r), -1), full_matrices=False)
    patterns = vt[:components].reshape(components, -1, 3)
    out, steps = [], []
    for i, p in enumerate(patterns):
        top = p[np.argmax(np.linalg.norm(p, axis=1))]
        sign = np.sign(top[1]) if abs(top[1]) > 1e-12 else np.sign(top[0]) or 1.0
        out.append(sign * p / np.linalg.norm(top))
        reach = np.abs(u[:, i]).max() * s[i] * np.linalg.norm(top)  # its largest coefficient, in these units
        steps.append(int(np.clip(np.ceil(REACH_STEPS * reach), LEAST_STEPS, MOST_STEPS)))
    return MotionBasis(np.asarray(vertices, dtype=np.int64), np.stack(out), over, np.array(steps))
