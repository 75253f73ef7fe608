"""A synthetic blink and a synthetic wide-open mouth go through enrolment, sender and receiver and
come out closing and wide open, measured by the tracker on the drawn picture.

The clip is the bundled speaker's own reference picture, drawn by the receiver's picture view with
a face made by hand: the lid model shut (codec/model/upper_face.py, lid 1 lays each upper lid on the
lower; codec/render/eyelids.py draws the shut lids' skin) and the lower face pulled down below the
mouth's slit. It is enrolled as a user enrols (its first second, its motion basis from all of it),
sent at fd-send's defaults and drawn by the library.
"""

from dataclasses import replace

import cv2
import numpy as np
import pytest

import facedeform
from facedeform.codec.model.deform import Deformer
from facedeform.common.parameters import EXTENDED_PARAMS
from facedeform.experiment.clips import track
from facedeform.receiver.face_view import PictureView
from facedeform.sender.calibrate import LOWER_LIP, UPPER_LIP, eye_opening, lip_gap
from facedeform.sender.session import stream_header
from tests.support import CLIP

FRAMES = 75
BLINKS = (8, 40, 60)  # first frames of three blinks of three frames
OPENINGS = (16, 46)  # first frames of two openings of twelve frames
WIDE = 0.15  # how far the lower face drops, in base-face units (face height 1): a wide-open mouth


def hand_made_faces(person) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """(pose-free faces, lids shut per frame, mouth drop per frame)."""
    rest = person.vertices
    slit = 0.5 * (rest[UPPER_LIP, 1] + rest[LOWER_LIP, 1])
    t = np.clip((slit + 0.06 - rest[:, 1]) / 0.12, 0.0, 1.0)
    below = t * t * (3.0 - 2.0 * t)  # how far each vertex follows the drop: smoothly from above the mouth
    loops = person.meta["loops"]
    below[loops["inner_lip_upper"]], below[loops["inner_lip_lower"]] = 0.0, 1.0
    lids, drop = np.zeros(FRAMES), np.zeros(FRAMES)
    for start in BLINKS:
        lids[start:start + 3] = 1.0
    for start in OPENINGS:
        drop[start:start + 12] = WIDE * np.sin(np.linspace(0.0, np.pi, 12))
    deformer, faces = Deformer(person), []
    for shut, down in zip(lids, drop):
        params = np.zeros(len(EXTENDED_PARAMS))
        params[[EXTENDED_PARAMS.index("lid_l"), EXTENDED_PARAMS.index("lid_r")]] = shut
        face = deformer.deform_extended(params)
        face[:, 1] -= down * below
        faces.append(face)
    return faces, lids, drop


@pytest.fixture(scope="module")
def round_trip(tmp_path_factory):
    person = facedeform.enroll(str(CLIP), seconds=1.0, motion=0).model
    person = replace(person, picture=replace(person.picture, shut_eyes=None, shut_eyes_at=None))  # the lid model's lids
    view = PictureView(stream_header(("rx",), 25.0, person.content_id), person, person.picture.image.shape[1::-1])
    faces, lids, drop = hand_made_faces(person)
    source = [view.render(np.zeros(1), shape=f) for f in faces]
    folder = tmp_path_factory.mktemp("hand_made")
    for i, rgb in enumerate(source):
        cv2.imwrite(str(folder / f"{i:04d}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    face = facedeform.enroll(str(folder), seconds=1.0)
    drawn = list(facedeform.decode(facedeform.encode(str(folder), face, embed_face=False), face))
    return track(source), track(drawn), lids, drop


@pytest.mark.slow
def test_a_blink_comes_out_closing(round_trip):
    """The tracker reads the hand-made shut eyes as only a quarter closed (a real shut eye reads about
    half: sender/fit.LID_GAIN), so the sender learns of half-shut lids and the receiver draws them so:
    the drawn eyes close in every blink frame, by far more than the open eyes' jitter, and nowhere else."""
    source, drawn, lids, _ = round_trip
    blink = lids > 0
    seen, got = eye_opening(source), eye_opening(drawn)
    assert seen[blink].mean() < 0.85 * seen[~blink].mean()  # the tracker sees the hand-made blink
    jitter = got[~blink].std()
    assert got[blink].max() < got[~blink].mean() - 2 * jitter
    assert got[~blink].mean() - got[blink].mean() > max(4 * jitter, 0.015)
    assert abs(got[~blink].mean() - seen[~blink].mean()) < 0.01


@pytest.mark.slow
def test_a_wide_open_mouth_comes_out_wide_open(round_trip):
    source, drawn, _, drop = round_trip
    wide, shut = drop > 0.8 * WIDE, drop == 0
    seen, got = lip_gap(source), lip_gap(drawn)
    assert seen[wide].mean() > 8 * seen[shut].mean()  # wide open, against lips that meet
    assert 0.85 < got[wide].mean() / seen[wide].mean() < 1.15
    assert got[shut].mean() < 2 * seen[shut].mean() + 0.01  # and closed again
