"""The mouth-and-jaw fidelity measure: 0 for the model's own faces, 1 for a frozen face, rms-based."""

import numpy as np
import pytest

from facedeform.codec.model.deform import Deformer
from facedeform.codec.model.face_model import load_base_face
from facedeform.common.parameters import EXTENDED_PARAMS, PAPER_PARAMS
from facedeform.sender.calibrate import inter_ocular
from facedeform.sender.fidelity import MOUTH_JAW_LANDMARKS, fidelity


@pytest.fixture(scope="module")
def deformer():
    return Deformer(load_base_face())


def faces(deformer, n=6, seed=3):
    rng = np.random.default_rng(seed)
    p = np.zeros((n, len(EXTENDED_PARAMS)))
    p[:, 0] = rng.uniform(0.0, 20.0, n)
    p[:, 1:13] = rng.normal(0.0, 0.02, (n, 12))
    p[:, EXTENDED_PARAMS.index("ry")] = 10.0  # the pose is ignored
    return p, np.stack([deformer.deform_extended(q * (np.arange(len(q)) < 13)) for q in p])


def test_landmark_set_is_41_distinct_mouth_and_jaw_vertices():
    assert len(MOUTH_JAW_LANDMARKS) == len(set(MOUTH_JAW_LANDMARKS)) == 41


def test_zero_for_model_faces_and_one_for_a_frozen_face(deformer):
    p, targets = faces(deformer)
    perfect = fidelity(deformer, targets, p, EXTENDED_PARAMS)
    assert perfect.error == pytest.approx(0.0, abs=1e-12) and perfect.relative == pytest.approx(0.0, abs=1e-12)
    frozen = fidelity(deformer, targets, np.zeros((len(p), 13)), PAPER_PARAMS)
    assert frozen.relative == pytest.approx(1.0) and frozen.error > 0.005


def test_is_the_rms_error_over_the_rms_motion(deformer):
    p, targets = faces(deformer)
    shifted = targets.copy()
    shifted[:, list(MOUTH_JAW_LANDMARKS)] += [0.01, 0.0, 0.0]  # an extra 0.01 on every compared landmark
    f = fidelity(deformer, shifted, p, EXTENDED_PARAMS)
    iod = inter_ocular(deformer.face.vertices)
    assert f.error * iod == pytest.approx(0.01)
    motion = shifted[:, list(MOUTH_JAW_LANDMARKS)] - deformer.face.vertices[list(MOUTH_JAW_LANDMARKS)]
    assert f.frozen * iod == pytest.approx(np.sqrt(np.mean(np.sum(motion**2, axis=-1))))
