"""fd-experiment end to end on 2 s of the bundled clip: rows, files, and bitrates that match the bytes."""

import csv
import json
from pathlib import Path

import pytest

from experiment.baselines import encode_decode
from experiment.cli import _clip, main
from protocol.framing import packet_size

ROOT = Path(__file__).resolve().parents[1]
CLIP = ROOT / "samples" / "grid_bbaf2n.mpg"


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    out = tmp_path_factory.mktemp("experiment")
    code = main([str(CLIP), "--out", str(out), "--seconds", "2", "--sizes", "128", "--qualities", "1", "3",
                 "--layouts", "paper", "personal", "--faces", "generic", "own", "--baselines", "x264", "--bitrates", "40", "--jobs", "1", "-q"])
    assert code == 0
    return out, json.loads((out / "results.json").read_text())


def test_one_row_per_run_in_csv_and_json(results):
    out, rows = results
    assert sorted((r["codec"], r["setting"]) for r in rows) == [
        ("ours-paper", "q1"), ("ours-paper", "q3"), ("ours-paper-own", "q1"), ("ours-paper-own", "q3"),
        ("ours-personal-own", "q1"), ("ours-personal-own", "q3"), ("x264", "40000bps")]
    with open(out / "results.csv") as f:
        assert len(list(csv.DictReader(f))) == 7
    for row in rows:
        assert row["frames"] == 50 and row["size"] == 128
        assert 0.0 <= row["akd_aligned"] < 0.5 and row["faces_found"] > 0.9
        assert 0.0 < row["motion_fidelity"] < 1.5


def test_our_bitrate_is_the_stream_file_without_its_header(results):
    out, rows = results
    model = (out / "work" / "grid_bbaf2n_128.fdface").stat().st_size
    for row in (r for r in rows if r["codec"].startswith("ours")):
        data = (out / "work" / f"grid_bbaf2n_128_{row['codec']}_{row['setting']}.fd").read_bytes()
        header = 1 + packet_size(data, 1)
        oneoff = header + (model if row["codec"].endswith("-own") else 0)
        assert (row["stream_bytes"], row["oneoff_bytes"]) == (len(data) - header, oneoff)
        assert row["bitrate_bps"] == pytest.approx(8 * row["stream_bytes"] * row["fps"] / row["frames"])


def test_sending_one_frame_in_two_is_a_run_of_its_own(results):
    from experiment.runs import run_ours

    out, rows = results
    clip = _clip("grid_bbaf2n", str(out / "work" / "grid_bbaf2n_128.mp4"), rows[0]["fps"])
    row, decoded = run_ours(clip, 3, "paper", out / "work", every=2)
    every_frame = next(r for r in rows if (r["codec"], r["setting"]) == ("ours-paper", "q3"))
    assert (row["codec"], row["setting"], len(decoded)) == ("ours-paper-every2", "q3", 50)
    assert row["bitrate_bps"] < every_frame["bitrate_bps"]
    assert (out / "work" / "grid_bbaf2n_128_ours-paper-every2_q3.fd").exists()


def test_baseline_bitrate_is_its_coded_bytes(results):
    out, rows = results
    row = next(r for r in rows if r["codec"] == "x264")
    clip = _clip("grid_bbaf2n", str(out / "work" / "grid_bbaf2n_128.mp4"), row["fps"])
    again = encode_decode(clip.frames, clip.fps, "x264", 40_000)
    assert row["stream_bytes"] == again.coded_bytes
    assert row["bitrate_bps"] == pytest.approx(8 * again.coded_bytes * row["fps"] / row["frames"])


def test_plots_and_side_by_side_are_written(results):
    out, _ = results
    for name in ("akd_aligned_128.png", "mouth_akd_aligned_128.png", "opening_corr_128.png",
                 "side_by_side_grid_bbaf2n_128.mp4"):
        assert (out / name).stat().st_size > 1000


def test_missing_clip_is_a_one_line_error(tmp_path, capsys):
    assert main([str(tmp_path / "nope.mp4"), "--out", str(tmp_path), "-q"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("fd-experiment: ") and err.count("\n") == 1
