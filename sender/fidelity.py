"""Geometry fidelity: how well the receiver's deformed mesh reproduces the tracked face.

Both sides are pose-free and in base-face units: the observed target (the base
face moved as the person moved from rest, ``RestFace.target``) and the base
mesh deformed by the sent parameters. The error is the mean distance over a
set of landmarks divided by the base face's inter-ocular distance; the
relative error divides it by the error of a frozen face (the base face at
rest), so 0 is a perfect model and 1 is no better than sending nothing.
"""

from dataclasses import dataclass

import numpy as np

from codec.deform import EXTENDED_PARAMS, Deformer
from sender.calibrate import inter_ocular


@dataclass(frozen=True)
class Fidelity:
    error: float  # mean landmark distance over inter-ocular distance
    frozen: float  # the same for the rest face

    @property
    def relative(self) -> float:
        return self.error / self.frozen if self.frozen > 0 else 0.0


def fidelity(deformer: Deformer, targets: np.ndarray, params: np.ndarray, names, landmarks) -> Fidelity:
    """targets (n, 468, 3) observed pose-free faces; params (n, k) in the layout ``names`` (any
    subset of EXTENDED_PARAMS; the head pose is ignored); landmarks: the vertex indices compared."""
    base = deformer.face.vertices
    slots = [EXTENDED_PARAMS.index(n) for n in names]
    full = np.zeros((len(params), len(EXTENDED_PARAMS)))
    full[:, slots] = params
    full[:, -6:] = 0.0  # pose-free: compare shapes, not placements
    idx = np.asarray(landmarks)
    model = np.stack([deformer.deform_extended(p)[idx] for p in full])
    obs = np.asarray(targets, dtype=np.float64)[:, idx]
    iod = inter_ocular(base)
    return Fidelity(float(np.linalg.norm(obs - model, axis=-1).mean() / iod),
                    float(np.linalg.norm(obs - base[idx], axis=-1).mean() / iod))
