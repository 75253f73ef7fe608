"""Geometry fidelity: how well the receiver's deformed mesh reproduces the tracked face.

Both sides are pose-free and in base-face units: the observed target (the base
face moved as the person moved from rest, ``RestFace.target``, so the base
face is the person's neutral) and the base mesh deformed by the sent
parameters. The error is the rms distance over a set of landmarks; the
relative error divides it by the rms of the landmarks' own motion about the
neutral (the error of a frozen face), so 0 is a perfect model and 1 is no
better than sending nothing.
"""

from dataclasses import dataclass

import numpy as np

from facedeform.codec.model.deform import Deformer, extended_params
from facedeform.common.parameters import POSE_PARAMS, slots
from facedeform.sender.calibrate import inter_ocular

_OUTER_LIPS = (61, 146, 91, 181, 84, 17, 314, 405, 321, 375,
               291, 409, 270, 269, 267, 0, 37, 39, 40, 185)  # fmt: skip
_INNER_LIPS = (78, 82, 13, 312, 308, 317, 14, 87)  # corners, and mid and half-way points of each lip
_JAW_LINE = (172, 136, 150, 149, 176, 148, 152, 377, 400, 378, 379, 365, 397)  # angle to angle via the chin
#: The 41 mouth and jaw landmarks the issue's fidelity measure is taken over.
MOUTH_JAW_LANDMARKS: tuple[int, ...] = _OUTER_LIPS + _INNER_LIPS + _JAW_LINE


@dataclass(frozen=True)
class Fidelity:
    error: float  # rms landmark distance over inter-ocular distance
    frozen: float  # rms of the landmarks' own motion about the neutral, over inter-ocular distance

    @property
    def relative(self) -> float:
        return self.error / self.frozen if self.frozen > 0 else 0.0


def fidelity(deformer: Deformer, targets: np.ndarray, params: np.ndarray, names,
             landmarks=MOUTH_JAW_LANDMARKS) -> Fidelity:
    """targets (n, 468, 3) observed pose-free faces; params (n, k) in the layout ``names`` (any
    subset of EXTENDED_PARAMS; the head pose is ignored); landmarks: the vertex indices compared."""
    base = deformer.face.vertices
    full = extended_params(names, params)
    full[:, slots(POSE_PARAMS)] = 0.0  # pose-free: compare shapes
    idx = np.asarray(landmarks)
    model = np.stack([deformer.deform_extended(p)[idx] for p in full])
    obs = np.asarray(targets, dtype=np.float64)[:, idx]
    iod = inter_ocular(base)
    def rms(d):
        return float(np.sqrt(np.mean(np.sum(d * d, axis=-1))))
    return Fidelity(rms(obs - model) / iod, rms(obs - base[idx]) / iod)
