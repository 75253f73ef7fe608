"""A long call holds no more memory than a short one: the sender keeps counters, not frames,
and its --dump goes to disk as the frames pass; and the looped and paced sources that long and
live calls are measured with (benchmarks/bench_memory.py, bench_latency.py, fd-send --realtime)."""

import tracemalloc
from pathlib import Path

import numpy as np
import pytest

import facedeform.sender.tracker
from facedeform.codec.model.face_model import load_base_face
from facedeform.receiver.session import ReceiveSession
from facedeform.receiver.transport import open_file
from facedeform.sender.analysis import FaceAnalyser, Smoothing
from facedeform.sender.config import SendConfig
from facedeform.sender.session import SendSession, read_dump
from facedeform.sender.sources import LoopedSource, PacedSource, VideoSource
from tests.support import ROOT

FPS = 25.0
LOST = 97  # every this many frames the face is lost for one frame


class LandmarkSource:
    """n synthetic "frames" that are (468, 3) landmarks in pixels: the base face, talking (the
    lower face moves down and up) and a little noisy; one in ``LOST`` carries no face."""

    fps, size, length = FPS, (640, 480), None

    def __init__(self, n: int) -> None:
        self.n = n

    def frames(self):
        base = np.asarray(load_base_face().vertices, dtype=np.float64)
        pixels = base * [200.0, -200.0, -200.0] + [320.0, 240.0, 0.0]
        lower = base[:, 1] < np.percentile(base[:, 1], 30)
        rng = np.random.default_rng(0)
        for i in range(self.n):
            if i % LOST == LOST - 1:
                yield None
                continue
            frame = pixels + rng.normal(0.0, 0.3, pixels.shape)
            frame[lower, 1] += 6.0 * (1 + np.sin(i / 4))
            yield frame.astype(np.float32)


class Replay:
    """A tracker whose frames are landmarks already (None: no face)."""

    def track(self, frame):
        return frame


@pytest.fixture
def replayed(monkeypatch):
    monkeypatch.setattr(facedeform.sender.tracker, "FaceTracker", Replay)


def send(n: int, dump=None) -> tuple[SendSession, int]:
    """(session, bytes) of an n-frame call at fd-send's defaults."""
    session = SendSession(LandmarkSource(n), SendConfig(), dump)
    size = sum(len(chunk) for chunk in session.stream())
    session.close()
    return session, size


def peak_bytes(n: int, dump) -> int:
    tracemalloc.start()
    try:
        send(n, dump)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.mark.slow
def test_a_six_times_longer_call_peaks_at_the_same_python_memory(replayed, tmp_path):
    send(60)  # imports, caches and compiled kernels before the measurement
    short = peak_bytes(250, tmp_path / "short.npz")
    long = peak_bytes(1500, tmp_path / "long.npz")
    # keeping each frame's analysis (as before) grew by about 17 KB a frame: 21 MB here
    assert long - short < 256 * 1024, (short, long)
    assert read_dump(tmp_path / "long.npz")[2].shape[0] == 1500


def test_the_dump_written_as_frames_pass_holds_every_frames_analysis(replayed, tmp_path):
    n = 120
    session, _ = send(n, tmp_path / "call.npz")
    assert session.frame_count == n and session.stats()["frames"] == n
    analyser = FaceAnalyser(Replay(), load_base_face(), FPS, "auto", round(FPS), smoothing=Smoothing())
    expected = list(analyser.run(LandmarkSource(n).frames()))
    seen = np.array([r.landmarks is not None for r in expected])
    assert not seen.all() and seen.any()
    with np.load(tmp_path / "call.npz") as d:
        assert tuple(d["names"]) == analyser.names == session.header.names
        np.testing.assert_array_equal(d["found"], seen)
        np.testing.assert_allclose(d["params"], [r.params for r in expected])
        np.testing.assert_allclose(d["landmarks"][seen], [r.landmarks for r in expected if r.landmarks is not None])
        np.testing.assert_allclose(d["targets"][seen], [r.target for r in expected if r.target is not None], rtol=1e-6)
        np.testing.assert_allclose(d["pose_rotation"][seen], [r.pose.rotation for r in expected if r.pose])
        np.testing.assert_allclose(d["pose_scale"][seen], [r.pose.scale for r in expected if r.pose])
        assert np.isnan(d["landmarks"][~seen]).all() and np.isnan(d["pose_translation"][~seen]).all()
        assert int(d["rest_frame"]) == analyser.rest.index
        assert (float(d["fps"]), int(d["width"]), int(d["height"])) == (FPS, 640, 480)
    names, fps, params, found = read_dump(tmp_path / "call.npz", analyser.names[:2])
    assert (names, fps, params.shape) == (analyser.names[:2], FPS, (n, 2))
    assert list(tmp_path.iterdir()) == [tmp_path / "call.npz"]  # the temporary files are gone


def test_no_frame_sent_writes_no_dump(replayed, tmp_path):
    session = SendSession(LandmarkSource(10), SendConfig(), tmp_path / "none.npz")
    session.close()
    assert list(tmp_path.iterdir()) == []


def test_a_looped_clip_runs_as_long_as_asked_across_its_ends():
    clip = ROOT / "samples" / "grid_bbaf2n.mpg"
    once = list(VideoSource(clip).frames())
    looped = LoopedSource(str(clip), seconds=(2 * len(once) + 5) / FPS)
    frames = list(looped.frames())
    assert looped.length == len(frames) == 2 * len(once) + 5 and looped.fps == FPS
    np.testing.assert_array_equal(frames[len(once) + 3], once[3])
    np.testing.assert_array_equal(frames[-1], once[4])


class Clock:
    """A clock that moves only when slept on (or when a test moves it)."""

    def __init__(self) -> None:
        self.now = 100.0

    def monotonic(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        assert seconds > 0
        self.now += seconds


def test_a_paced_source_hands_frames_over_no_faster_than_its_rate(monkeypatch):
    clock = Clock()
    monkeypatch.setattr("facedeform.sender.sources.time", clock)
    source = LandmarkSource(11)
    source.fps = 200.0
    handed = [clock.now for _ in PacedSource(source).frames()]
    np.testing.assert_allclose(np.diff(handed), 1 / 200.0)


def test_a_paced_source_hands_a_frame_that_was_slow_to_read_at_once(monkeypatch):
    clock, source = Clock(), LandmarkSource(5)
    source.fps = 10.0
    inner = source.frames

    def slow_third():
        for i, frame in enumerate(inner()):
            clock.now += 0.35 if i == 2 else 0.0  # the third frame is read 0.25 s after it was due
            yield frame

    monkeypatch.setattr(source, "frames", slow_third)
    monkeypatch.setattr("facedeform.sender.sources.time", clock)
    handed = [clock.now for _ in PacedSource(source).frames()]
    late = [0.0, 0.1, 0.45, 0.45, 0.45]  # the frames after a late one come at once until they are due again
    np.testing.assert_allclose(np.array(handed) - handed[0], late)


class NullSink:
    def write(self, image) -> None:
        pass

    def close(self) -> None:
        pass


def receive_peak(path: Path, dump: Path) -> tuple[int, ReceiveSession]:
    """(Python peak bytes, session) of fd-recv's session over the stream file at ``path``, 64x64."""
    session = ReceiveSession(lambda fps, size: [NullSink()], (64, 64), dump=str(dump))
    tracemalloc.start()
    try:
        session.run(open_file(str(path), None, None))
        session.close()
        return tracemalloc.get_traced_memory()[1], session
    finally:
        tracemalloc.stop()


@pytest.mark.slow
def test_a_six_times_longer_call_peaks_at_the_same_python_memory_in_the_receiver(replayed, tmp_path):
    for n in (60, 500, 3000):
        session = SendSession(LandmarkSource(n), SendConfig())
        (tmp_path / f"{n}.fd").write_bytes(b"".join(session.stream()))
    receive_peak(tmp_path / "60.fd", tmp_path / "60.npz")  # compiled kernels and caches first
    short, _ = receive_peak(tmp_path / "500.fd", tmp_path / "500.npz")
    long, session = receive_peak(tmp_path / "3000.fd", tmp_path / "3000.npz")
    assert session.frames == 3000 and session.stats(1.0)["frames"] == 3000
    # keeping every decoded frame (as before) grew by about 0.5 KB a frame: 1.25 MB here
    assert long - short < 256 * 1024, (short, long)
    with np.load(tmp_path / "3000.npz") as dump:
        assert dump["params"].shape[0] == 3000 and list(dump["seq"][:3]) == [0, 1, 2]
