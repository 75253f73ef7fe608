"""Low-latency smoothing: the One Euro filter (Casiez, Roussel and Vogel, CHI 2012).

Tracker jitter of a pixel or two on a still face is coded as motion: it costs
most of the stream's bits and shows as shimmer. A fixed low-pass would make a
fast mouth lag; the One Euro filter is a first-order low-pass whose cutoff
rises with the signal's speed, so it smooths hard at rest and hardly at all in
fast motion.
"""

import numpy as np


def _alpha(cutoff, rate: float):
    """Exponential-smoothing weight of a first-order low-pass at ``cutoff`` Hz sampled at ``rate`` Hz."""
    return 1.0 / (1.0 + rate / (2 * np.pi * cutoff))


class OneEuroFilter:
    """Filters arrays of a fixed shape sampled at ``rate`` Hz, each element in units of ``scale``.

    ``scale`` (broadcastable to the values) makes one unit mean the same to
    every element (e.g. a quantiser step), so one ``min_cutoff`` (Hz) and
    ``beta`` (Hz per unit/s) serve angles and displacements alike.
    """

    def __init__(self, rate: float, scale, min_cutoff: float = 1.0, beta: float = 0.05,
                 derivative_cutoff: float = 1.0) -> None:
        self.rate, self.scale = float(rate), np.asarray(scale, dtype=np.float64)
        self.min_cutoff, self.beta, self.derivative_cutoff = min_cutoff, beta, derivative_cutoff
        self._value: np.ndarray | None = None
        self._speed: np.ndarray | None = None

    def reset(self) -> None:
        """Forget the past (after a gap): the next value passes unchanged."""
        self._value = None

    def __call__(self, value: np.ndarray) -> np.ndarray:
        x = np.asarray(value, dtype=np.float64) / self.scale
        if self._value is None:
            self._value, self._speed = x, np.zeros_like(x)
            return x * self.scale
        a_d = _alpha(self.derivative_cutoff, self.rate)
        self._speed = a_d * (x - self._value) * self.rate + (1 - a_d) * self._speed
        a = _alpha(self.min_cutoff + self.beta * np.abs(self._speed), self.rate)
        self._value = a * x + (1 - a) * self._value
        return self._value * self.scale
