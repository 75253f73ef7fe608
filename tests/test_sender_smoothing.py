"""One Euro smoothing: still in, still out; a step is followed quickly; the dead band holds."""

import numpy as np
import pytest

from sender.analysis import Smoothing
from sender.smoothing import OneEuroFilter

RATE = 25.0


def test_still_input_gives_constant_output_after_settling():
    rng = np.random.default_rng(0)
    f = OneEuroFilter(RATE, np.array([0.25, 0.002]))
    out = np.array([f(np.array([3.0, 0.05]) + rng.normal(0, [0.1, 0.0008])) for _ in range(200)])
    still = np.array([f(np.array([3.0, 0.05])) for _ in range(100)])
    assert np.ptp(still[-50:], axis=0).max() < 1e-6
    np.testing.assert_allclose(still[-1], [3.0, 0.05], atol=1e-5)
    # jitter is damped: the output moves less than half as much as the input
    assert (out[50:].std(axis=0) < 0.5 * np.array([0.1, 0.0008])).all()


@pytest.mark.parametrize("height", [4.0, 40.0])  # quantiser steps: a small and a large mouth move
def test_step_reaches_90_percent_quickly(height):
    f = OneEuroFilter(RATE, 1.0, min_cutoff=1.0, beta=0.05)
    for _ in range(10):
        f(np.zeros(1))
    frames = next(i for i in range(1, 100) if f(np.full(1, height))[0] >= 0.9 * height)
    assert frames <= (6 if height < 10 else 3)


def test_reset_passes_the_next_value():
    f = OneEuroFilter(RATE, 1.0)
    f(np.zeros(2))
    f.reset()
    np.testing.assert_array_equal(f(np.ones(2)), np.ones(2))


def test_strength_zero_is_off():
    assert Smoothing(0.0).filter(RATE, 1.0) is None
    strong, weak = Smoothing(2.0).filter(RATE, 1.0), Smoothing(0.5).filter(RATE, 1.0)
    assert strong.min_cutoff < weak.min_cutoff and strong.beta < weak.beta
