"""Analysis by synthesis: the fit inverts the receiver's model exactly, and the fidelity measure's ends."""

import numpy as np
import pytest

from codec.deform import EXTENDED_PARAMS, PAPER_PARAMS, Deformer
from codec.face_model import load_base_face
from codec.mouth import MOUTH_PARAMS
from codec.upper_face import UPPER_PARAMS
from sender.fidelity import fidelity
from sender.fit import ModelFit

UPPER = slice(len(PAPER_PARAMS), len(PAPER_PARAMS) + len(UPPER_PARAMS))


@pytest.fixture(scope="module")
def model():
    deformer = Deformer(load_base_face())
    return deformer, ModelFit(deformer, ridge=0.0)


def random_faces(n: int, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    p = np.zeros((n, len(EXTENDED_PARAMS)))
    p[:, 0] = rng.uniform(-10.0, 40.0, n)
    p[:, 1:13] = rng.normal(0.0, 0.03, (n, 12))
    p[:, UPPER] = rng.uniform(-0.5, 1.0, (n, len(UPPER_PARAMS)))
    return p


def test_fit_recovers_model_generated_parameters(model):
    deformer, fit = model
    for p in random_faces(10):
        target = deformer.deform_extended(p)
        np.testing.assert_allclose(fit.paper(target), p[:13], atol=1e-6)
        np.testing.assert_allclose(fit.upper(target), p[UPPER], atol=1e-6)


def test_theta_stays_in_range(model):
    deformer, fit = model
    p = np.zeros(len(EXTENDED_PARAMS))
    p[0] = 80.0
    assert fit.paper(deformer.deform_extended(p))[0] == pytest.approx(45.0)


def test_fidelity_is_zero_for_the_model_and_one_for_a_frozen_face(model):
    deformer, fit = model
    p = random_faces(5, seed=2)
    targets = np.stack([deformer.deform_extended(q) for q in p])
    perfect = fidelity(deformer, targets, p, EXTENDED_PARAMS, fit.lower)
    assert perfect.error == pytest.approx(0.0, abs=1e-12) and perfect.relative == pytest.approx(0.0, abs=1e-12)
    frozen = fidelity(deformer, targets, np.zeros_like(p), EXTENDED_PARAMS, fit.lower)
    assert frozen.relative == pytest.approx(1.0) and frozen.error > 0.01
    paper_only = fidelity(deformer, targets, p[:, :13], PAPER_PARAMS, fit.upper_landmarks)
    assert paper_only.relative == pytest.approx(1.0)  # the paper's set leaves the upper face at rest


def test_mouth_fit_recovers_the_richer_mouth_and_leaves_the_paper_fit_alone(model):
    deformer, paper_fit = model
    fit = ModelFit(deformer, ridge=0.0, mouth=True)
    mouth = [EXTENDED_PARAMS.index(n) for n in MOUTH_PARAMS]
    rng = np.random.default_rng(4)
    for p in random_faces(5, seed=3):
        p[mouth] = rng.normal(0.0, 0.02, len(mouth))
        target = deformer.deform_extended(p)
        np.testing.assert_allclose(fit.paper(target), np.r_[p[:13], p[mouth]], atol=1e-6)
    assert set(paper_fit.lower) <= set(fit.lower) and len(paper_fit.paper(target)) == 13
