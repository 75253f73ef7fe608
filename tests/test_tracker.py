"""Face tracker: MediaPipe's landmarks on real clips, None without a face, the larger of two faces."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from facedeform.common.errors import InputError
from facedeform.sender.detector import load_model
from facedeform.sender.tracker import FaceTracker
from tests.support import ROOT

DEV = Path(__file__).resolve().parents[2] / "shared" / "samples" / "dev"
GRID = ROOT / "samples" / "grid_bbaf2n.mpg"
MAX_MEDIAN_PX = 1.0


@pytest.fixture(scope="module")
def tracker() -> FaceTracker:
    return FaceTracker()


@pytest.fixture(autouse=True)
def fresh(tracker):
    tracker.reset()


def frames(path: Path, limit: int | None = None) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    out = []
    while limit is None or len(out) < limit:
        ok, frame = cap.read()
        if not ok:
            break
        out.append(frame)
    cap.release()
    assert out, f"{path}: no frames read"
    return out


def reference(clip: str) -> dict:
    path = DEV / f"{clip}.landmarks.npz"
    if not path.exists():
        pytest.skip(f"the dev clips' reference landmarks ({path.name}) are not beside this checkout")
    with np.load(path) as ref:
        return {k: ref[k] for k in ref.files}


def check_against_reference(tracked: list, ref: dict) -> None:
    """Median x, y distance over frames where both found a face, and z in the same pixel scale."""
    w, h = int(ref["width"]), int(ref["height"])
    pairs = [(ours, theirs * [w, h, w]) for ours, theirs, found
             in zip(tracked, ref["landmarks"], ref["found"]) if found and ours is not None]
    assert pairs
    ours, theirs = (np.stack(a) for a in zip(*pairs))
    assert np.median(np.linalg.norm(ours[..., :2] - theirs[..., :2], axis=-1)) <= MAX_MEDIAN_PX
    assert np.median(np.abs(ours[..., 2] - theirs[..., 2])) <= MAX_MEDIAN_PX


def test_bundled_grid_clip_has_a_face_in_every_frame(tracker):
    video = frames(GRID)
    tracked = [tracker.track(f) for f in video]
    assert all(t is not None for t in tracked)
    h, w = video[0].shape[:2]
    for t in tracked:
        assert t.shape == (468, 3) and t.dtype == np.float32
        assert (t[:, 0] >= 0).all() and (t[:, 0] < w).all() and (t[:, 1] >= 0).all() and (t[:, 1] < h).all()
    # The nose tip is nearer the camera than the face's outline.
    assert all(t[1, 2] < t[[234, 454], 2].min() for t in tracked)
    if DEV.exists():
        ref = reference("lipnet_bbaf2n")
        assert len(ref["found"]) == len(video)
        check_against_reference(tracked, ref)


def test_matches_reference_on_a_512_clip(tracker):
    ref = reference("sadtalker_WDA_KatieHill_000")
    video = frames(DEV / "sadtalker_WDA_KatieHill_000.mp4", limit=50)
    check_against_reference([tracker.track(f) for f in video], ref)


@pytest.mark.parametrize("pattern", ["grey", "noise", "black"])
def test_no_face_gives_none(tracker, pattern):
    rng = np.random.default_rng(0)
    frame = {"grey": np.full((288, 360, 3), 128, np.uint8),
             "noise": rng.integers(0, 256, (288, 360, 3), dtype=np.uint8),
             "black": np.zeros((288, 360, 3), np.uint8)}[pattern]
    assert tracker.track(frame) is None


def test_face_leaving_the_frame_is_let_go(tracker):
    first = frames(GRID, limit=1)[0]
    assert tracker.track(first) is not None
    assert tracker.track(np.full_like(first, 128)) is None
    assert tracker.track(first) is not None


def test_two_faces_give_the_larger(tracker):
    face = frames(GRID, limit=1)[0]
    face_width = np.ptp(tracker.track(face)[:, 0])
    small = cv2.resize(face, None, fx=0.6, fy=0.6)
    small = np.pad(small, ((0, face.shape[0] - small.shape[0]), (0, 0), (0, 0)))
    for canvas, big_from in ((np.hstack([small, face]), small.shape[1]), (np.hstack([face, small]), 0)):
        tracker.reset()
        points = tracker.track(canvas)
        assert points is not None and points.shape == (468, 3)
        x = points[:, 0]
        assert big_from <= x.min() and x.max() < big_from + face.shape[1]
        assert np.ptp(x) == pytest.approx(face_width, rel=0.05)


def test_mirrored_pair_gives_one_face(tracker):
    face = frames(GRID, limit=1)[0]
    points = tracker.track(np.hstack([face, face[:, ::-1]]))
    assert points is not None and points.shape == (468, 3)
    width = face.shape[1]
    assert points[:, 0].max() < width or points[:, 0].min() >= width


def test_missing_model_is_an_input_error():
    with pytest.raises(InputError, match="no_such_model.tflite"):
        load_model("no_such_model.tflite")


def test_the_models_load_on_an_opencv_without_a_classic_engine(monkeypatch):
    """OpenCV 4 and 5.1 have no ENGINE_CLASSIC (5.0 has): the models load on the engine they have."""
    monkeypatch.delattr(cv2.dnn, "ENGINE_CLASSIC", raising=False)
    assert not load_model("face_landmark.tflite").empty()
