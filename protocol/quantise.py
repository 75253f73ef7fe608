"""Uniform scalar quantisation of parameter vectors.

The encoder sends integers; both ends turn them back into the same floats, so
what the receiver renders is exactly what the sender's dump of decoded values
predicts.
"""

import numpy as np

#: Quantiser step per kind of parameter (degrees for angles, base-face units
#: for displacements), the default of stream version 1.
ANGLE_STEP = 0.25
VECTOR_STEP = 0.002


def steps_for(names: tuple[str, ...]) -> np.ndarray:
    """(k,) float64 step of each named parameter: angles in degrees, vectors in base-face units."""
    return np.array([ANGLE_STEP if _is_angle(n) else VECTOR_STEP for n in names])


def _is_angle(name: str) -> bool:
    return name in ("theta", "rx", "ry", "rz")


def quantise(values: np.ndarray, steps: np.ndarray) -> list[int]:
    """(k,) floats -> k Python ints (msgpack packs small ints in one byte)."""
    return [int(q) for q in np.rint(np.asarray(values, dtype=np.float64) / steps)]


def dequantise(indices, steps: np.ndarray) -> np.ndarray:
    """k ints -> (k,) float64 values."""
    return np.asarray(indices, dtype=np.float64) * steps
