"""User mistakes across the tools: each is one line on stderr and a non-zero exit, caught before the work."""

import subprocess
import sys

import pytest

from tests.support import CLIP, RECV, ROOT, SEND, assert_one_line_error, run

ANIMATE = [sys.executable, "-m", "facedeform.receiver.animate"]
SCRIPT = str(ROOT / "samples" / "animation.txt")


@pytest.mark.parametrize("args, message", [
    ([SCRIPT, "-o", "/nonexistent/a.mp4"], "does not exist"),
    ([SCRIPT, "-o", SCRIPT], "is the input"),
    ([SCRIPT, "--fps", "nan"], "out of range"),
    ([SCRIPT, "--fps", "0"], "out of range"),
])
def test_animate_mistakes(args, message):
    result = run(ANIMATE + args)
    assert_one_line_error(result, "fd-animate")
    assert message in result.stderr.decode()


def test_animate_refuses_a_script_of_absurd_length(tmp_path):
    script = tmp_path / "long.txt"
    script.write_text("0 neutral\n10000000 smile\n")
    result = run(ANIMATE + [str(script), "-o", str(tmp_path / "a.mp4")])
    assert_one_line_error(result, "fd-animate")
    assert "lasts" in result.stderr.decode() and not (tmp_path / "a.mp4").exists()


@pytest.mark.parametrize("destination, message", [
    ("udp://127.0.0.1:0", "port must be 1 to 65535"),
    ("udp://nonexistent.invalid:5000", "unknown host"),
    ("tcp://nonexistent.invalid:5000", "unknown host"),
])
def test_send_destinations_that_cannot_be_are_refused_before_the_work(destination, message):
    result = run(SEND + [str(CLIP), "-o", destination])
    assert_one_line_error(result, "fd-send")
    assert message in result.stderr.decode()


@pytest.fixture(scope="module")
def stream_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("stream") / "s.fd"
    assert run(SEND + [str(CLIP), "-q", "-o", str(path)]).returncode == 0
    return path


@pytest.mark.parametrize("args, message", [
    (["-o", "/nonexistent/x.mp4"], "does not exist"),
    (["-o", "{tmp}/x.mp4", "--dump", "/nonexistent/d.npz"], "does not exist"),
    (["-o", "{stream}"], "is the input"),
    (["-o", "{tmp}"], "is a folder"),
])
def test_receive_outputs_are_checked_before_the_work(stream_file, tmp_path, args, message):
    args = [a.format(tmp=tmp_path, stream=stream_file) for a in args]
    result = run(RECV + [str(stream_file), *args])
    assert_one_line_error(result, "fd-recv")
    assert message in result.stderr.decode()
    assert stream_file.stat().st_size > 0


def test_experiment_output_folder_that_cannot_be_made_is_one_line():
    result = run([sys.executable, "-m", "facedeform.experiment.cli", str(CLIP), "--out", "/proc/no-such-folder"])
    assert_one_line_error(result, "fd-experiment")
    assert "cannot make the folder" in result.stderr.decode()


@pytest.mark.parametrize("tool, args", [
    ("facedeform.sender.enroll", [str(CLIP), "-o", "{tmp}/f.fdface", "--seconds", "nan"]),
    ("facedeform.sender.enroll", [str(CLIP), "-o", "{tmp}/f.fdface", "--motion-seconds", "-1"]),
    ("facedeform.receiver.cli", ["--listen", "udp://127.0.0.1:0", "--timeout", "inf"]),
])
def test_durations_that_are_not_finite_and_positive_are_refused(tool, args, tmp_path):
    result = run([sys.executable, "-m", tool, *[a.format(tmp=tmp_path) for a in args]])
    assert result.returncode == 2 and "out of range" in result.stderr.decode()
    assert len(result.stderr.decode().strip().splitlines()) == 1


def test_sizes_keep_proportions_unless_both_sides_are_given():
    from facedeform.common.cli import fitted, parse_size

    assert parse_size("640x480") == (640, 480) and fitted((640, 480), (360, 288)) == (640, 480)
    assert parse_size("256") == (256, 0) and fitted((256, 0), (360, 288)) == (256, 204)
    assert fitted((640, 0), (1920, 1080)) == (640, 360)


def test_keygen_refuses_to_write_a_key_to_stdout(tmp_path):
    result = subprocess.run([sys.executable, "-m", "facedeform.sender.keygen", "-"], cwd=tmp_path,
                            capture_output=True, timeout=60)
    assert_one_line_error(result, "fd-keygen")
    assert not (tmp_path / "-").exists()


@pytest.mark.parametrize("script", ["bench_expression.py", "bench_picture_layer.py"])
def test_a_benchmark_given_a_missing_clip_says_so_in_one_line(script, tmp_path):
    result = run([sys.executable, str(ROOT / "benchmarks" / script), "/nonexistent/clip.mp4", "--out", str(tmp_path)])
    assert_one_line_error(result, script)
    assert "no such file" in result.stderr.decode()


@pytest.mark.parametrize("script, args", [("bench_expression.py", ["--params", "nosuch"]),
                                          ("bench_picture_layer.py", ["--rates", "fast"])])
def test_a_benchmark_given_a_wrong_argument_says_so_in_one_line(script, args, tmp_path):
    """The benchmarks parse their arguments as the CLIs do (common.cli.ArgumentParser): a wrong one is one
    line naming the script, not argparse's usage block."""
    result = run([sys.executable, str(ROOT / "benchmarks" / script), str(CLIP), *args, "--out", str(tmp_path)])
    assert_one_line_error(result, script)
    assert result.returncode == 2 and "invalid" in result.stderr.decode()
