"""Lids in the default layouts and shut lids in the whole picture."""

from dataclasses import replace

import numpy as np

from facedeform.codec.model.deform import Deformer
from facedeform.codec.model.face_model import load_base_face
from facedeform.codec.render.eyelids import Eyelids
from facedeform.codec.render.picture import SceneMesh
from facedeform.common.parameters import EXTENDED_PARAMS
from facedeform.receiver.face_view import PictureView
from facedeform.sender.fit import LID_GAIN, ModelFit
from facedeform.sender.session import stream_header
from tests.support import a_picture

BASE = load_base_face()
LIDS = [EXTENDED_PARAMS.index("lid_l"), EXTENDED_PARAMS.index("lid_r")]


def shut(left: float, right: float) -> np.ndarray:
    params = np.zeros(len(EXTENDED_PARAMS))
    params[LIDS] = left, right
    return Deformer(BASE).deform_extended(params)


def test_the_fit_finds_the_lids_the_rest_of_the_layout_leaves_over():
    fit = ModelFit(Deformer(BASE))
    got = fit.lids(shut(0.4, 0.15), ("theta",), np.zeros(1))
    np.testing.assert_allclose(got, [LID_GAIN * 0.4, LID_GAIN * 0.15], atol=1e-3)  # as the tracker under-reports
    np.testing.assert_allclose(fit.lids(shut(0.7, 0.0), ("theta",), np.zeros(1)), [1.0, 0.0], atol=1e-3)
    np.testing.assert_allclose(fit.lids(BASE.vertices, ("theta",), np.zeros(1)), [0.0, 0.0], atol=1e-9)


def test_shut_lids_show_skin_over_the_eye_and_nothing_else_changes():
    face = replace(BASE, picture=a_picture(160, 160))
    scene = SceneMesh(face, face.picture)
    lids = Eyelids(face, scene.rest_pixels, (160, 160))
    assert lids.weights(BASE.vertices) == (0.0, 0.0)
    assert lids.weights(shut(1.0, 0.0)) == (0.0, 1.0)  # face-right first: lid_r
    picture = face.picture.image
    assert lids.apply(picture, (0.0, 0.0)) is picture
    closed = lids.apply(picture, (1.0, 1.0))
    changed = np.any(closed != picture, axis=2)
    eyes = np.round(scene.rest_pixels[[159, 386]]).astype(int)  # the upper lids' middles
    assert all(changed[y, x] for x, y in eyes)
    assert changed.mean() < 0.05  # the eyes only


def test_a_view_draws_shut_eyes_when_the_lids_meet():
    face = replace(BASE, picture=a_picture(160, 160))
    names = ("lid_l", "lid_r")
    view = PictureView(stream_header(names, 25.0, BASE.content_id), face, (160, 160))
    open_, closed, again = view.render(np.zeros(2)), view.render(np.ones(2)), view.render(np.zeros(2))
    assert np.any(open_ != closed)
    np.testing.assert_array_equal(open_, again)  # opening again restores the picture exactly
