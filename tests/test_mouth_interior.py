"""The person's open mouth in a mouth less open: teeth only between the lips, at their own size."""

import numpy as np
import pytest

from facedeform.codec.model.face_model import mouth_vertices
from facedeform.codec.render.mouth_interior import MouthInterior
from facedeform.receiver.face_view import PictureView
from facedeform.sender.session import stream_header


@pytest.fixture(scope="module")
def person(enrolled_3s):
    assert enrolled_3s.picture.mouth is not None
    return enrolled_3s


def interior_of(face) -> MouthInterior:
    loops = face.meta["loops"]
    return MouthInterior(face.picture.mouth, face.picture.mouth_points, mouth_vertices(face),
                         loops["inner_lip_upper"], loops["inner_lip_lower"])


def test_teeth_move_only_between_the_lips_and_go_as_they_close(person):
    interior = interior_of(person)
    image = person.picture.mouth
    assert interior.drawn(1.0) is image
    half = interior.drawn(0.5)
    points = dict(zip(mouth_vertices(person).tolist(), person.picture.mouth_points))
    upper = np.array([points[v] for v in person.meta["loops"]["inner_lip_upper"]])
    lower = np.array([points[v] for v in person.meta["loops"]["inner_lip_lower"]])
    changed = np.any(half != image, axis=2)
    rows = np.nonzero(changed)[0]
    assert changed.any() and rows.min() >= np.floor(upper[:, 1].min()) - 1 and rows.max() <= np.ceil(
        lower[:, 1].max()) + 1  # nothing outside the inner lips
    # shut, each half of the opening shows only what lies at its lip: no teeth's height is left
    shut = interior_of(person).drawn(0.0)
    x = int(round(points[13][0]))
    top = np.interp(x, *upper[np.argsort(upper[:, 0])].T)
    bottom = np.interp(x, *lower[np.argsort(lower[:, 0])].T)
    mid = (top + bottom) / 2
    upper_rows = shut[int(np.ceil(top)):int(np.ceil(mid)), x].astype(int)
    lower_rows = shut[int(np.ceil(mid)):int(np.floor(bottom)) + 1, x].astype(int)
    assert len(upper_rows) > 2 and len(lower_rows) > 2
    assert np.ptp(upper_rows, axis=0).max() <= 1 and np.ptp(lower_rows, axis=0).max() <= 1


def test_a_face_drawn_frame_by_frame_is_the_face_drawn_at_once(person):
    """The texture's mouth and eyes are patched as they change: a view that drew other frames first
    (the sender's, a receiver in a call) draws each frame as a view drawing only it."""
    names = ("theta", "v3y", "lid_l", "lid_r")
    header = stream_header(names, 25.0, person.content_id)
    size = person.picture.image.shape[1::-1]
    frames = [np.array([t, -0.02 * t / 10, lid, 0.5 * lid]) for t, lid in
              ((0.0, 0.0), (4.0, 0.3), (10.0, 0.9), (6.0, 1.0), (2.0, 0.0))]
    running = PictureView(header, person, size)
    for params in frames:
        np.testing.assert_array_equal(running.render(params), PictureView(header, person, size).render(params))
