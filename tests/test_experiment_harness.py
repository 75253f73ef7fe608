"""fd-experiment end to end on 2 s of the bundled clip: every measure present and in range, bitrates that
are the streams' bytes, the same rows from a Dask cluster, and a resumed run that redoes nothing."""

import argparse
import csv
import functools
import json
import math
import multiprocessing
import shutil
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest

from facedeform.common.errors import FdError
from facedeform.experiment import cli
from facedeform.experiment.cli import _clip, main
from facedeform.protocol.framing import packet_size
from tests.support import CLIP

ARGS = ["--seconds", "2", "--sizes", "128", "--qualities", "--levels", "3", "--baselines", "x264", "--rungs", "3", "-q"]
PIXEL = {"psnr": (5, 60), "psnr_p5": (5, 60), "ssim": (-1, 1), "ms_ssim": (0, 1), "vmaf": (0, 100)}
KEYPOINT = {"akd": (0, 1), "mouth_akd": (0, 1), "akd_aligned": (0, 0.5), "mouth_akd_aligned": (0, 0.5),
            "opening_corr": (-1, 1), "opening_swing": (0.3, 3), "eye_corr": (-1, 1), "motion_fidelity": (0, 1.5)}
SPEED = ("encode_fps", "decode_fps")


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    out = tmp_path_factory.mktemp("experiment")
    assert main([str(CLIP), "--out", str(out), "--jobs", "1", *ARGS]) == 0
    return out, json.loads((out / "results.json").read_text())


@pytest.mark.slow
def test_one_row_per_run_in_csv_json_and_its_own_file(results):
    out, rows = results
    assert sorted((r["codec"], r["setting"]) for r in rows) == [
        ("ours-auto-own", "l3"), ("x264", "crf45"), ("x264", "crf48"), ("x264", "crf51")]
    with open(out / "results.csv") as f:
        assert [(r["codec"], r["setting"]) for r in csv.DictReader(f)] == [(r["codec"], r["setting"]) for r in rows]
    assert sorted(p.name for p in (out / "rows").iterdir()) == [
        "grid_bbaf2n_128_ours-auto-own_l3.json", "grid_bbaf2n_128_x264_crf45.json", "grid_bbaf2n_128_x264_crf48.json",
        "grid_bbaf2n_128_x264_crf51.json"]


@pytest.mark.slow
def test_every_measure_is_present_and_in_range(results):
    _, rows = results
    for row in rows:
        assert row["frames"] == 50 and row["size"] == 128 and row["fps"] == 25
        for key, (lo, hi) in PIXEL.items():
            assert lo <= row[key] <= hi, (row["codec"], row["setting"], key, row[key])
        assert row["psnr_p5"] <= row["psnr"]
        assert row["encode_fps"] > 0 and row["decode_fps"] > 0
    # the finest x264 and ours find the face in every frame; x264's floor at 128x128 may lose it
    for row in (r for r in rows if r["setting"] in ("l3", "crf45")):
        assert row["faces_found"] > 0.9
        for key, (lo, hi) in KEYPOINT.items():
            assert lo <= row[key] <= hi, (row["codec"], key, row[key])
    x264 = sorted((r for r in rows if r["codec"] == "x264"), key=lambda r: r["bitrate_bps"])
    assert [r["setting"] for r in x264] == ["crf51", "crf48", "crf45"]  # the floor is the lowest rate
    assert x264[0]["vmaf"] < x264[-1]["vmaf"] and x264[0]["psnr"] < x264[-1]["psnr"]


@pytest.mark.slow
def test_the_same_video_measures_as_identical(results):
    from facedeform.experiment.runs import measure

    out, rows = results
    clip = _clip("grid_bbaf2n", str(out / "work" / "grid_bbaf2n_128.mkv"), rows[0]["fps"])
    same = measure(clip, clip.frames)
    assert same["psnr"] > 60 and same["psnr_p5"] > 60 and same["vmaf"] > 95
    assert same["ssim"] == pytest.approx(1) and same["ms_ssim"] == pytest.approx(1)
    assert same["akd"] == 0 and same["mouth_akd"] == 0 and same["opening_corr"] == pytest.approx(1)


@pytest.mark.slow
def test_our_rates_are_the_stream_file_and_the_one_off_bytes(results):
    out, rows = results
    model = (out / "work" / "grid_bbaf2n_128.fdface").stat().st_size
    row = next(r for r in rows if r["codec"] == "ours-auto-own")
    data = (out / "work" / "grid_bbaf2n_128_ours-auto-own_l3.fd").read_bytes()
    header = 1 + packet_size(data, 1)
    assert (row["stream_bytes"], row["oneoff_bytes"]) == (len(data) - header, header + model)
    per_frame = 8 * (len(data) - header) * 25 / 50
    np.testing.assert_allclose(row["bitrate_bps"], per_frame)
    np.testing.assert_allclose(row["bitrate_oneoff_bps"], per_frame + 8 * (header + model) * 25 / 250)
    # a 2-second clip is one window: the costliest is the whole stream after its header
    assert row["costliest_2s_bps"] == pytest.approx(per_frame, rel=0.02)


@pytest.mark.slow
def test_baseline_rates_are_their_stream_files(results):
    out, rows = results
    for row in (r for r in rows if r["codec"] == "x264"):
        size = (out / "work" / f"grid_bbaf2n_128_x264_{row['setting']}.264").stat().st_size
        assert row["stream_bytes"] == size and row["oneoff_bytes"] == 0
        np.testing.assert_allclose([row["bitrate_bps"], row["bitrate_oneoff_bps"]], 8 * size * 25 / 50)


@pytest.mark.slow
def test_the_crop_is_lossless_and_follows_the_rule(results):
    from facedeform.experiment.clips import read_video

    out, _ = results
    info = json.loads((out / "work" / "grid_bbaf2n_128.json").read_text())
    assert info["frames"] == 50 and info["box"]["side"] > 0
    frames = read_video(out / "work" / "grid_bbaf2n_128.mkv")
    assert len(frames) == 50 and frames[0].shape == (128, 128, 3)


@pytest.mark.slow
def test_plots_table_and_side_by_side_are_written(results):
    out, _ = results
    for name in ("psnr_128.png", "vmaf_128.png", "ms_ssim_128.png", "mouth_akd_128.png", "opening_corr_128.png",
                 "overview_128.png", "side_by_side_grid_bbaf2n_128.mp4"):
        assert (out / name).stat().st_size > 1000
    table = (out / "table.md").read_text()
    assert "ours, auto, l3, own face" in table and "x264 crf51 (floor)" in table
    assert "x264 crf45 (~3x floor)" in table or "x264 crf48 (~3x floor)" in table


@pytest.mark.slow
def test_a_second_run_redoes_no_finished_row(results, monkeypatch, capsys):
    out, rows = results

    def fail(task):
        raise AssertionError(f"redone: {task['key']}")

    monkeypatch.setattr(cli, "execute", fail)
    assert main([str(CLIP), "--out", str(out), "--jobs", "1", *ARGS]) == 0, capsys.readouterr().err
    assert json.loads((out / "results.json").read_text()) == rows


@pytest.mark.slow
def test_a_dask_cluster_gives_the_same_rows(results, tmp_path):
    distributed = pytest.importorskip("distributed")
    out, rows = results
    again = tmp_path / "again"
    shutil.copytree(out / "work", again / "work")  # the crop and face model, not the rows
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        assert main([str(CLIP), "--out", str(again), "--scheduler", cluster.scheduler_address, *ARGS]) == 0
    theirs = json.loads((again / "results.json").read_text())
    assert len(theirs) == len(rows) == 4
    for mine, dask in zip(rows, theirs):
        for key in mine:
            if key in SPEED:
                continue
            if isinstance(mine[key], float) and math.isnan(mine[key]):
                assert math.isnan(dask[key]), key
            else:
                assert dask[key] == mine[key], (mine["codec"], mine["setting"], key)


def test_missing_baseline_encoder_is_a_one_line_error(tmp_path, capsys, monkeypatch):
    from facedeform.experiment import baselines

    listed = baselines._listed("encoders")
    monkeypatch.setattr(baselines, "_listed", lambda kind: listed.replace(" libsvtav1 ", " gone "))
    assert main([str(CLIP), "--out", str(tmp_path), "--baselines", "x264", "av1", "-q"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("fd-experiment: baseline av1: encoder libsvtav1 is missing") and err.count("\n") == 1


def test_missing_clip_is_a_one_line_error(tmp_path, capsys):
    assert main([str(tmp_path / "nope.mp4"), "--out", str(tmp_path), "-q"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("fd-experiment: ") and err.count("\n") == 1


def test_crop_box_rule():
    from facedeform.experiment.clips import crop_box

    lm = np.full((3, 468, 3), np.nan)
    lm[0, :, :2] = np.linspace([200, 100], [260, 180], 468)  # 60 wide, 80 high
    lm[1, :, :2] = np.linspace([210, 100], [270, 180], 468)  # moved right: the union is 70 x 80
    lm[:2, :, 2] = 0.0
    # side 1.8 x 80 = 144 about the union's centre (235, 140) moved up by 14.4
    assert crop_box(lm, 640, 480) == (163, 54, 144)
    assert crop_box(lm - [0, 90, 0], 640, 480) == (163, 0, 144)  # shifted down to stay inside
    assert crop_box(lm, 250, 120) == (130, 0, 120)  # shrunk to the frame's height, shifted inside


def test_the_lossless_crop_reads_back_bit_for_bit_through_opencv_too(tmp_path):
    import cv2

    from facedeform.experiment.clips import read_video, write_lossless
    from facedeform.sender.sources import VideoSource

    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (32, 32, 3), dtype=np.uint8) for _ in range(4)]
    write_lossless(tmp_path / "c.mkv", frames, 25.0)
    for back in (read_video(tmp_path / "c.mkv"),
                 [cv2.cvtColor(f, cv2.COLOR_BGR2RGB) for f in VideoSource(tmp_path / "c.mkv").frames()]):
        assert len(back) == 4
        for a, b in zip(frames, back):
            np.testing.assert_array_equal(a, b)


@pytest.mark.slow
def test_resuming_with_another_clip_length_is_refused(results, capsys):
    out, _ = results
    args = [a if a != "2" else "3" for a in ARGS]
    assert main([str(CLIP), "--out", str(out), *args]) == 1
    err = capsys.readouterr().err
    assert "made with --seconds 2.0, not 3.0: use another --out" in err and err.count("\n") == 1


def _held_or_failing(folder, release, task: int) -> int:
    if task == 0:
        raise FdError("run 0 failed")
    (folder / str(task)).touch()  # this run started
    release.wait()  # until the pool has cancelled the runs it had not handed out
    return task


def test_a_failed_run_ends_the_local_pool_at_once(tmp_path, monkeypatch):
    shutdown = ProcessPoolExecutor.shutdown
    with multiprocessing.Manager() as manager:
        release = manager.Event()

        def cancel_then_release(self, wait=True, *, cancel_futures=False):
            shutdown(self, wait=False, cancel_futures=cancel_futures)
            release.set()
            shutdown(self, wait=wait)

        monkeypatch.setattr(ProcessPoolExecutor, "shutdown", cancel_then_release)
        with pytest.raises(FdError, match="^run 0 failed$"):
            list(cli._map(functools.partial(_held_or_failing, tmp_path, release), list(range(40)),
                          argparse.Namespace(scheduler=None, jobs=2)))
    assert len(list(tmp_path.iterdir())) <= 8  # the runs already handed to the 2 workers, not the other 39


def test_rows_of_an_older_run_without_a_newer_measure_still_plot():
    """A resumed run keeps the rows it finished, written perhaps before a measure was added."""
    from facedeform.experiment.report import curves

    old = {"codec": "x264", "setting": "crf51", "size": 256, "bitrate_bps": 9000.0, "psnr": 24.0}
    new = {**old, "setting": "crf45", "bitrate_bps": 15000.0, "eye_corr": 0.5}
    x, y = curves([old, new], 256, "eye_corr")["x264"]
    assert list(x) == [15.0] and list(y) == [0.5]
