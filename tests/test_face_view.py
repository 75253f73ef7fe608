"""The receiver's view: layouts it accepts, faces it refuses, and that parameters reach the pixels."""

import numpy as np
import pytest

from facedeform.codec.model.face_model import load_base_face
from facedeform.common.errors import BitstreamError
from facedeform.common.parameters import PAPER_PARAMS
from facedeform.protocol.stream import Header, steps_for
from facedeform.receiver.face_view import FaceView

FACE = load_base_face()
SIZE = (96, 96)


def view(names, face_id=FACE.content_id):
    """A view of a header as a stream may carry it: its steps written out, whatever the names."""
    return FaceView(Header(25.0, names, np.full(len(names), 0.01), face_id), FACE, SIZE)


def test_rest_parameters_render_the_face_in_the_middle():
    image = view(PAPER_PARAMS).render(np.zeros(len(PAPER_PARAMS)))
    background = image[0, 0]
    assert image.shape == (96, 96, 3)
    assert np.any(image[48, 48] != background)
    assert np.all(image[2, 2] == background)


def test_opening_the_jaw_changes_the_mouth_not_the_forehead():
    v = view(PAPER_PARAMS)
    rest, open_ = v.render(np.zeros(13)), v.render(np.r_[15.0, np.zeros(12)])
    change = np.abs(rest.astype(int) - open_.astype(int)).max(axis=2)
    assert change[55:80].max() > 40
    assert change[:30].max() <= 1  # rounding of shared sums at most: no forehead vertex moves


def test_head_rotation_in_a_layout_turns_the_head():
    names = PAPER_PARAMS + ("rx", "ry", "rz")
    v = view(names)
    still, turned = v.render(np.zeros(16)), v.render(np.r_[np.zeros(13), 0.0, 30.0, 0.0])
    assert np.mean(np.any(still != turned, axis=2)) > 0.05


def test_any_subset_of_the_extended_layout_is_accepted():
    v = view(("lid_l", "lid_r", "theta"))
    assert v.render(np.array([1.0, 1.0, 5.0])).shape == (96, 96, 3)


@pytest.mark.parametrize("names", [("theta", "wiggle"), ("theta", "theta")])
def test_unknown_layouts_are_refused(names):
    with pytest.raises(BitstreamError, match="unknown parameter layout"):
        view(names)


def test_a_stream_for_another_face_is_refused():
    with pytest.raises(BitstreamError, match="made for face model"):
        view(PAPER_PARAMS, face_id="ab" * 32)


def _pupil_column(image):
    """Mean column of the dark pixels on the face (the pupils), background left out."""
    upper = image[: image.shape[0] // 2]  # eyes, not the mouth
    on_face = np.any(upper != image[0, 0], axis=2)
    rows, cols = np.nonzero(on_face & (upper.astype(int).sum(axis=2) < 200))
    return cols.mean()


def test_gaze_moves_the_irises_toward_the_face_own_left():
    v = view(("gaze_yaw",))
    right, ahead, left = (v.render(np.array([g])) for g in (-25.0, 0.0, 25.0))
    assert _pupil_column(right) + 1.0 < _pupil_column(ahead) < _pupil_column(left) - 1.0


def test_a_face_with_a_texture_is_drawn_with_it():
    from dataclasses import replace

    red = np.zeros((32, 32, 3), np.uint8)
    red[..., 0] = 200
    image = FaceView(Header(25.0, PAPER_PARAMS, steps_for(PAPER_PARAMS), FACE.content_id),
                     replace(FACE, texture=red), SIZE).render(np.zeros(13))
    plain = view(PAPER_PARAMS).render(np.zeros(13))
    cheek = (slice(40, 56), slice(30, 40))
    assert image[cheek][..., 0].mean() > 2 * image[cheek][..., 1:].mean()  # red skin, lit
    assert np.abs(image[cheek].astype(int) - plain[cheek]).mean() > 20


def test_a_fallback_face_can_be_drawn_for_another_id():
    header = Header(25.0, PAPER_PARAMS, steps_for(PAPER_PARAMS), "ab" * 32)
    assert FaceView(header, FACE, SIZE, check_id=False).render(np.zeros(13)).shape == (96, 96, 3)
