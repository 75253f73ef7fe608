"""One Euro smoothing: still in, still out; a step is followed quickly; a still face under camera
noise keeps the receiver's picture still."""


import cv2
import numpy as np
import pytest

from facedeform.codec.model.face_model import load_base_face
from facedeform.protocol.stream import PacketEncoder
from facedeform.sender.analysis import FaceAnalyser, Smoothing
from facedeform.sender.session import stream_header
from facedeform.sender.smoothing import OneEuroFilter
from facedeform.sender.tracker import FaceTracker
from tests.support import CLIP

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
    f = Smoothing().filter(RATE, 1.0)
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


def picture_changes(frames, smoothing: float) -> float:
    """Fraction of frames after the first second in which what the receiver shows changes, with
    fd-send's layout, header and dead zone."""
    base = load_base_face()
    analyser = FaceAnalyser(FaceTracker(), base, RATE, smoothing=Smoothing(smoothing))
    encoder = PacketEncoder(stream_header(analyser.names, RATE, base.content_id), 2)
    shown = []
    for result in analyser.run(frames):
        encoder.frame(result.params, result.landmarks is not None)
        shown.append(encoder.reconstruction)
    return float(np.mean(np.any(np.diff(shown[round(RATE):], axis=0) != 0, axis=1)))


def test_a_still_face_under_camera_noise_stays_still():
    ok, frame = cv2.VideoCapture(str(CLIP)).read()
    assert ok
    rng = np.random.default_rng(1)
    noisy = [np.clip(frame + rng.normal(0, 3.0, frame.shape), 0, 255).astype(np.uint8) for _ in range(75)]
    assert picture_changes(noisy, 1.0) <= 0.05
    assert picture_changes(noisy, 0.0) >= 0.2  # the filter, not the dead zone alone, keeps it still
