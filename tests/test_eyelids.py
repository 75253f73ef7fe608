"""Lids in the default layouts and shut lids in the whole picture."""

from dataclasses import replace

import cv2
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


def test_the_speakers_own_shut_eyes_replace_the_drawn_skin_where_the_face_file_has_them():
    face = replace(BASE, picture=a_picture(160, 160))
    scene = SceneMesh(face, face.picture)
    x0, y0, x1, y1 = Eyelids(face, scene.rest_pixels, (160, 160)).box
    own = np.zeros((y1 - y0 + 4, x1 - x0 + 4, 3), np.uint8)
    own[..., 1] = 222  # a colour the picture nowhere has
    with_own = replace(face, picture=replace(face.picture, shut_eyes=own, shut_eyes_at=(x0 - 2, y0 - 2)))
    closed = Eyelids(with_own, scene.rest_pixels, (160, 160)).region(face.picture.image, (1.0, 1.0))
    middles = (scene.rest_pixels[[159, 386]] + scene.rest_pixels[[145, 374]]) / 2  # between the lids
    eyes = np.round(middles - [x0, y0]).astype(int)
    assert all(np.abs(closed[y, x].astype(int) - (0, 222, 0)).max() <= 4 for x, y in eyes)  # the speaker's own
    half = Eyelids(with_own, scene.rest_pixels, (160, 160)).region(face.picture.image, (0.5, 0.5))
    assert half[..., 2].min() >= 50  # not before the lids meet (the picture's blue is 50 or more, the own eyes' 0)
    elsewhere = replace(with_own, picture=replace(with_own.picture, shut_eyes_at=(x0 + 1, y0)))  # short of the box
    drawn = Eyelids(elsewhere, scene.rest_pixels, (160, 160)).region(face.picture.image, (1.0, 1.0))
    np.testing.assert_array_equal(drawn, Eyelids(face, scene.rest_pixels, (160, 160)).region(face.picture.image,
                                                                                            (1.0, 1.0)))


def test_enrolment_lays_the_speakers_own_shut_eyes_on_his_open_ones(enrolled_3s):
    """The sample clip's speaker blinks: his face carries his shut eyes, where the open eyes' dark
    irises give way to lid skin and the skin around them stays where it was (laid on the same place)."""
    picture = enrolled_3s.picture
    assert picture.shut_eyes is not None
    (x, y), (height, width) = picture.shut_eyes_at, picture.shut_eyes.shape[:2]
    open_ = picture.image[y:y + height, x:x + width].astype(float).mean(axis=2)
    change = picture.shut_eyes.astype(float).mean(axis=2) - open_
    rest = SceneMesh(enrolled_3s, picture).rest_pixels
    eyes = np.zeros((height, width), np.uint8)
    for ring in (enrolled_3s.meta["loops"]["eye_left"], enrolled_3s.meta["loops"]["eye_right"]):
        cv2.fillPoly(eyes, [np.round(rest[ring] - (x, y)).astype(np.int32)], 1)
    around = cv2.dilate(eyes, np.ones((9, 9), np.uint8)) == 0
    assert change[eyes > 0].mean() > 6  # lids where the irises were
    assert np.abs(change[around]).mean() < 8  # the brows and cheeks in their places
