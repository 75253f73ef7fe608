"""Uniform scalar quantisation with steps set by a quality level, and the encoder's dead zone.

Both ends turn the integers back into the same floats, so what the receiver
renders is exactly what the sender's dump of decoded values predicts. The steps
of each level and why they are small enough are in docs/bitstream.md.

The encoder may send an index other than the nearest one: :func:`hold_or_round`
keeps the index the decoder already holds while the value stays within a dead
zone of it (an unchanged value costs a fraction of a bit), so tracker jitter
smaller than the dead zone is not sent and a still face does not flicker. The
decoder does not know the dead zone; it bounds the error instead of half a step.
"""

import numpy as np

from facedeform.common.parameters import PARAMETERS, STEPS

QUALITIES = (1, 2, 3, 4, 5)  # coarse to fine
DEFAULT_QUALITY = 3  # the level whose steps the registry holds (common/parameters.py)
#: A displacement's step at the default level, in base-face units.
VECTOR_STEP = STEPS["length"]
#: Default dead zone in steps: one step, as the sender's hold was before it moved here (then fixed at
#: level 3's steps); 0.5 is plain rounding. Bits and errors of each are in docs/bitstream.md.
DEAD_ZONE = 1.0


def steps_for(names: tuple[str, ...], quality: int = DEFAULT_QUALITY) -> np.ndarray:
    """(k,) float64 step of each named parameter; each level halves the steps of the one below.
    ValueError for a level that is none or a name the registry does not hold."""
    if quality not in QUALITIES:
        raise ValueError(f"quality must be one of {QUALITIES}, not {quality!r}")
    unknown = [n for n in names if n not in PARAMETERS]
    if unknown:
        raise ValueError(f"no parameter is named {unknown[0]!r}")
    scale = 2.0 ** (DEFAULT_QUALITY - quality)
    return np.array([PARAMETERS[n].step * scale for n in names])


def quantise(values: np.ndarray, steps: np.ndarray) -> list[int]:
    """(k,) floats -> k Python ints."""
    return [int(q) for q in np.rint(np.asarray(values, dtype=np.float64) / steps)]


def hold_or_round(values: np.ndarray, steps: np.ndarray, held: list[int] | None,
                  dead_zone: float | np.ndarray) -> list[int]:
    """(k,) floats -> k ints: ``held`` (the decoder's last indices) where a value is less than
    ``dead_zone`` steps from it (one for all, or (k,) one each), elsewhere the nearest index: error at
    most ``max(dead_zone, 0.5)`` steps.

    ``dead_zone`` 0.5 (or ``held`` None) is plain :func:`quantise`: a held index that close is the nearest.
    """
    nearest = quantise(values, steps)
    if held is None:
        return nearest
    near = np.abs(np.asarray(values, dtype=np.float64) / steps - held) < dead_zone
    return [h if keep else n for h, n, keep in zip(held, nearest, near)]


def dequantise(indices, steps: np.ndarray) -> np.ndarray:
    """k ints -> (k,) float64 values."""
    return np.asarray(indices, dtype=np.float64) * steps
