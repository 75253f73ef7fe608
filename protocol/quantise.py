"""Uniform scalar quantisation with steps set by a quality level.

Both ends turn the integers back into the same floats, so what the receiver
renders is exactly what the sender's dump of decoded values predicts. The steps
of each level and why they are small enough are in docs/bitstream.md.
"""

import numpy as np

from codec.errors import BitstreamError

QUALITIES = (1, 2, 3, 4, 5)  # coarse to fine
DEFAULT_QUALITY = 3
#: Steps at the default level: degrees for angles, base-face units for displacements, and for
#: the lids (0 open .. 1 closed) a step that moves the lid about as far as VECTOR_STEP does.
ANGLE_STEP = 0.25
VECTOR_STEP = 0.002
LID_STEP = 0.05
ANGLES = ("theta", "rx", "ry", "rz", "gaze_yaw", "gaze_pitch")
LIDS = ("lid_l", "lid_r")
#: Typical bits per frame of the paper layout at 25 fps per level, measured by
#: benchmarks/bench_bitstream.py on the dev clips (4 frames per packet); drives :func:`quality_for_bitrate`.
TYPICAL_BITS = {1: 34.0, 2: 45.0, 3: 57.0, 4: 70.0, 5: 83.0}


def steps_for(names: tuple[str, ...], quality: int = DEFAULT_QUALITY) -> np.ndarray:
    """(k,) float64 step of each named parameter; each level halves the steps of the one below."""
    if quality not in QUALITIES:
        raise BitstreamError(f"quality must be one of {QUALITIES}, not {quality!r}")
    scale = 2.0 ** (DEFAULT_QUALITY - quality)
    return np.array([(ANGLE_STEP if n in ANGLES else LID_STEP if n in LIDS else VECTOR_STEP) * scale
                     for n in names])


def quality_for_bitrate(bits_per_second: float, fps: float) -> int:
    """The finest level whose typical rate fits ``bits_per_second`` (open loop: a guide, not a cap)."""
    fitting = [q for q in QUALITIES if TYPICAL_BITS[q] * fps <= bits_per_second]
    return max(fitting, default=QUALITIES[0])


def quantise(values: np.ndarray, steps: np.ndarray) -> list[int]:
    """(k,) floats -> k Python ints."""
    return [int(q) for q in np.rint(np.asarray(values, dtype=np.float64) / steps)]


def dequantise(indices, steps: np.ndarray) -> np.ndarray:
    """k ints -> (k,) float64 values."""
    return np.asarray(indices, dtype=np.float64) * steps
