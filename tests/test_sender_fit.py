"""Analysis by synthesis: the fit inverts the receiver's model exactly, and the fidelity measure's ends."""

import numpy as np
import pytest

from facedeform.codec.model.deform import Deformer, extended_params
from facedeform.codec.model.face_model import load_base_face
from facedeform.common.parameters import EXTENDED_PARAMS, MOUTH_PARAMS, PAPER_PARAMS, UPPER_PARAMS, slots
from facedeform.sender.fidelity import fidelity
from facedeform.sender.fit import ModelFit

UPPER = slice(len(PAPER_PARAMS), len(PAPER_PARAMS) + len(UPPER_PARAMS))
MOUTH = slots(MOUTH_PARAMS)
#: About the largest brow, lid and cheek values fd-send --params full produced on the dev clips.
UPPER_SPAN = np.array([0.03, 0.03, 0.03, 0.03, 0.5, 0.5, 0.03, 0.03])


@pytest.fixture(scope="module")
def model():
    deformer = Deformer(load_base_face())
    return deformer, ModelFit(deformer, ridge=0.0)


def random_faces(n: int, seed: int = 1, mouth: float = 0.0) -> np.ndarray:
    """(n, len(EXTENDED_PARAMS)) parameters of faces the refined rule draws as sent (none that its fold
    guard would change), with the mouth's extra points ``mouth`` apart (standard deviation)."""
    rng = np.random.default_rng(seed)
    deformer = Deformer(load_base_face())
    faces = []
    while len(faces) < n:
        p = np.zeros(len(EXTENDED_PARAMS))
        p[0] = rng.uniform(-10.0, 40.0)
        p[1:13] = rng.normal(0.0, 0.03, 12)
        p[UPPER] = rng.uniform(-1.0, 1.0, len(UPPER_PARAMS)) * UPPER_SPAN
        p[MOUTH] = rng.normal(0.0, mouth, len(MOUTH))
        if not deformer.would_fold(p):
            faces.append(p)
    return np.array(faces)


def test_fit_recovers_model_generated_parameters(model):
    deformer, fit = model
    for p in random_faces(10):
        target = deformer.deform_extended(p)
        np.testing.assert_allclose(fit.paper(target), p[:13], atol=1e-6)
        np.testing.assert_allclose(fit.upper(target), p[UPPER], atol=1e-6)


def test_theta_stays_in_range():
    """Under the paper's rule, which draws a jaw opened past 33 degrees folded, the fit stops at 45;
    under the refined rule it sends the widest opening up to 45 that folds nothing."""
    p = np.zeros(len(EXTENDED_PARAMS))
    p[0] = 80.0
    paper = Deformer(load_base_face(), "paper")
    assert ModelFit(paper).paper(paper.blend(p))[0] == pytest.approx(45.0)
    refined = Deformer(load_base_face())
    theta = ModelFit(refined).paper(refined.blend(p))[0]
    assert 30.0 < theta <= 45.0 and not refined.would_fold(extended_params(PAPER_PARAMS, [theta] + [0.0] * 12))


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
    for p in random_faces(5, seed=3, mouth=0.02):
        target = deformer.deform_extended(p)
        np.testing.assert_allclose(fit.paper(target), np.r_[p[:13], p[MOUTH]], atol=1e-6)
    assert set(paper_fit.lower) <= set(fit.lower) and len(paper_fit.paper(target)) == 13


@pytest.mark.parametrize("mouth", [False, True])
def test_a_face_that_would_fold_is_fitted_again_without_folding(model, mouth):
    """A lower lip pressed 0.15 below the jaw's carry toward the chin: the best fit would fold the
    lip's skin, the fit sent does not, and it is no further from the target than what the receiver's
    fold guard makes of the face as sent."""
    deformer, _ = model
    fit = ModelFit(deformer, ridge=0.0, mouth=mouth)
    names = PAPER_PARAMS + (MOUTH_PARAMS if mouth else ())
    for theta in (5.0, 12.0):
        sent = np.zeros(len(EXTENDED_PARAMS))
        sent[0] = theta
        sent[4:7] = deformer.feature_vectors(sent[:13], True)[0][2] + [0.0, -0.15, 0.0]
        assert deformer.would_fold(sent)
        target = deformer.blend(sent)  # the face as sent, folded
        params = fit.paper(target)
        assert not deformer.would_fold(extended_params(names, params))
        def error(p, target=target):
            return np.linalg.norm(deformer.deform_extended(p)[fit.lower] - target[fit.lower])

        assert error(extended_params(names, params)) <= error(sent) + 1e-12


def test_a_speaker_whose_tracked_blink_stays_half_open_has_it_drawn_shut():
    """The tracker brings some speakers' lids only partly together in a full blink (the bundled clip's
    to 0.64 of their rest gap): once such a blink is seen, the deepest closing is drawn shut and the
    gain that does so applies from then on; closings never deeper than a blink's keep LID_GAIN."""
    from facedeform.sender.fit import BLINK_GAP, LID_GAIN

    deformer = Deformer(load_base_face())
    rest = deformer.blend(extended_params((), np.zeros(0)))
    mild, blinking = ModelFit(deformer), ModelFit(deformer)

    def closed(fraction: float) -> np.ndarray:  # each upper-lid landmark moved that far to its lower partner
        target = rest.copy()
        for upper, lower in mild._lid_pairs:
            target[upper] += fraction * (rest[lower] - rest[upper])
        return target

    np.testing.assert_allclose(mild.lids(closed(0.15), (), np.zeros(0)), LID_GAIN * 0.15, atol=1e-9)
    assert 1 - 0.15 >= BLINK_GAP
    np.testing.assert_allclose(blinking.lids(closed(0.36), (), np.zeros(0)), 1.0, atol=1e-9)  # shut
    np.testing.assert_allclose(blinking.lids(closed(0.15), (), np.zeros(0)), 0.15 / 0.36, atol=1e-9)
