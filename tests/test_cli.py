"""fd-send and fd-recv end to end on the bundled clip, and every user mistake as one line."""

import importlib.metadata
import json
import subprocess
import sys
from pathlib import Path

import av
import cv2
import numpy as np
import pytest

import facedeform
from facedeform.protocol.quantise import DEAD_ZONE
from facedeform.sender.calibrate import lip_gap
from tests.support import CLIP, RECV, ROOT, SEND, assert_one_line_error, clip_frames, coded_error, parse_y4m, run


def test_pipe_gives_one_frame_per_input_frame_at_its_rate(tmp_path):
    out = tmp_path / "out.mp4"
    result = subprocess.run(f"{' '.join(SEND)} {CLIP} -q | {' '.join(RECV)} -q -o {out} --size 256",
                            shell=True, capture_output=True, cwd=ROOT, timeout=300)
    assert result.returncode == 0, result.stderr.decode()
    with av.open(str(out)) as container:
        stream = container.streams.video[0]
        decoded = list(container.decode(stream))
        rate = float(stream.average_rate)
    assert len(decoded) == clip_frames()
    assert rate == pytest.approx(cv2.VideoCapture(str(CLIP)).get(cv2.CAP_PROP_FPS))
    assert (decoded[0].width, decoded[0].height) == (256, 204)  # 360x288 at 256 wide, its proportions kept


def test_sender_dump_has_landmarks_pose_and_params(sent):
    from facedeform.common.parameters import LAYOUTS

    _, dump = sent
    n = clip_frames()
    assert tuple(dump["names"]) == LAYOUTS["mouth"]  # the default for a face without a motion basis
    assert dump["landmarks"].shape == (n, 468, 3)
    assert dump["found"].all()
    assert dump["params"].shape == (n, len(dump["names"]))
    assert dump["pose_rotation"].shape == (n, 3, 3)
    np.testing.assert_allclose(np.linalg.det(dump["pose_rotation"]), 1.0, atol=1e-6)


def test_decoded_jaw_angle_follows_the_mouth_opening(sent, tmp_path):
    stream, dump = sent
    result = run(RECV + ["-q", "-o", str(tmp_path / "out.y4m"), "--size", "64", "--dump", str(tmp_path / "recv.npz")],
                 stdin=stream)
    assert result.returncode == 0, result.stderr.decode()
    decoded = np.load(tmp_path / "recv.npz")
    theta = decoded["params"][:, list(decoded["names"]).index("theta")]
    gap = [lip_gap(lm) for lm in dump["landmarks"]]
    # the default smoothing delays theta by about one frame (40 ms): allow that lag, no more
    assert max(np.corrcoef(theta[k:], gap[:len(gap) - k])[0, 1] for k in range(2)) > 0.8
    # the receiver holds what the sender meant, to within the encoder's dead zone in every coded value:
    # by default the principal components of the first second's motion
    header, error = coded_error(stream, decoded["params"], dump["params"])
    assert header.basis is not None
    assert np.all(error <= DEAD_ZONE * (1 + 1e-9))


def test_sending_one_frame_in_two_halves_the_frames_coded(sent, tmp_path):
    stream, _ = sent
    dump = tmp_path / "send.npz"
    half = run(SEND + [str(CLIP), "--send-every", "2", "--json", "--dump", str(dump)])
    assert half.returncode == 0, half.stderr.decode()
    assert json.loads(half.stderr.decode().splitlines()[-1])["send_every"] == 2
    assert len(half.stdout) < len(stream)
    result = run(RECV + ["-q", "-o", str(tmp_path / "out.y4m"), "--size", "32", "--dump", str(tmp_path / "recv.npz")],
                 stdin=half.stdout)
    assert result.returncode == 0, result.stderr.decode()
    decoded, meant = np.load(tmp_path / "recv.npz")["params"], np.load(dump)["params"]
    assert len(decoded) == len(meant) == clip_frames()
    # frames sent are what the sender meant, to within the dead zone; the others lie halfway between
    header, error = coded_error(half.stdout, decoded[::2], meant[::2])
    assert header.divisor == 2 and np.all(error <= DEAD_ZONE * (1 + 1e-9))
    n = len(decoded) - 1 - (len(decoded) - 1) % 2  # the last frame sent
    np.testing.assert_allclose(decoded[1:n:2], (decoded[0:n - 1:2] + decoded[2:n + 1:2]) / 2, atol=1e-12)
    assert np.array_equal(decoded[n:], np.repeat(decoded[n:n + 1], len(decoded) - n, axis=0))  # then held


def test_unsmoothed_jaw_angle_follows_the_mouth_opening_without_lag(tmp_path):
    result = run(SEND + [str(CLIP), "--smoothing", "0", "-o", "/dev/null", "--dump", str(tmp_path / "send.npz")])
    assert result.returncode == 0, result.stderr.decode()
    dump = np.load(tmp_path / "send.npz")
    theta = dump["params"][:, list(dump["names"]).index("theta")]
    assert np.corrcoef(theta, [lip_gap(lm) for lm in dump["landmarks"]])[0, 1] > 0.8


def test_y4m_on_stdout(sent):
    stream, _ = sent
    result = run(RECV + ["-q", "-o", "-", "--size", "32x48"], stdin=stream)
    assert result.returncode == 0, result.stderr.decode()
    fields, count = parse_y4m(result.stdout)
    assert (fields[b"W"], fields[b"H"], count) == (b"32", b"48", clip_frames())


def test_truncated_stream_keeps_the_good_frames(sent, tmp_path):
    from facedeform.protocol.framing import packet_size

    stream, _ = sent
    header = 1 + packet_size(stream, 1)  # sync byte and header packet
    out = tmp_path / "out.y4m"
    result = run(RECV + ["-q", "-o", str(out), "--size", "32"], stdin=stream[: (header + len(stream)) // 2])
    assert_one_line_error(result, "fd-recv")
    assert "truncated" in result.stderr.decode()
    _, count = parse_y4m(out.read_bytes())
    assert 0 < count < clip_frames()


def no_face_video(path: Path) -> Path:
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=25)
        stream.width, stream.height, stream.pix_fmt = 128, 128, "yuv420p"
        for i in range(10):
            img = np.full((128, 128, 3), 90 + i, np.uint8)
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return path


@pytest.mark.parametrize("case, message", [
    ("missing", "no such file"),
    ("text", "not a video"),
    ("noface", "no face"),
])
def test_sender_errors(tmp_path, case, message):
    path = {"missing": tmp_path / "nope.mp4",
            "text": tmp_path / "notes.mp4",
            "noface": tmp_path / "grey.mp4"}[case]
    if case == "text":
        path.write_text("this is not a video\n")
    if case == "noface":
        no_face_video(path)
    result = run(SEND + [str(path)])
    assert_one_line_error(result, "fd-send")
    assert message in result.stderr.decode()
    assert result.stdout == b""


@pytest.mark.parametrize("data, message", [
    (b"", "empty input"),
    (b"\x00garbage garbage garbage" * 10, "not an fd stream"),
])
def test_receiver_errors(data, message):
    result = run(RECV + ["-o", "-"], stdin=data)
    assert_one_line_error(result, "fd-recv")
    assert message in result.stderr.decode()


@pytest.mark.parametrize("args, prog", [
    (SEND, "fd-send"), (SEND + [str(CLIP), "--bogus"], "fd-send"), (RECV + ["--size", "abc"], "fd-recv"),
])
def test_bad_arguments_are_one_line(args, prog):
    result = run(args)
    assert_one_line_error(result, prog)
    assert result.returncode == 2


@pytest.mark.parametrize("module, prog", [
    ("sender.cli", "fd-send"), ("receiver.cli", "fd-recv"), ("sender.enroll", "fd-enroll"),
    ("receiver.animate", "fd-animate"), ("experiment.cli", "fd-experiment"), ("sender.keygen", "fd-keygen"),
])
def test_every_tool_says_its_version_and_nothing_else(module, prog):
    result = run([sys.executable, "-m", f"facedeform.{module}", "--version"])
    assert result.returncode == 0 and result.stdout.decode() == f"{prog} {facedeform.__version__}\n"
    assert importlib.metadata.version("facedeform") == facedeform.__version__  # the package's, one place


@pytest.fixture(scope="module")
def face_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("face") / "me.fdface"
    result = run([sys.executable, "-m", "facedeform.sender.enroll", str(CLIP), "-o", str(path), "-q"])
    assert result.returncode == 0, result.stderr.decode()
    return path


def test_a_personal_face_travels_in_the_stream(face_file, tmp_path):
    sent = run(SEND + [str(CLIP), "--face", str(face_file), "--json"])
    assert sent.returncode == 0, sent.stderr.decode()
    stats = json.loads(sent.stderr.decode().strip().splitlines()[-1])
    assert stats["header_bytes"] > face_file.stat().st_size  # the model goes once, counted apart
    assert stats["bits_per_frame"] < 200
    out = tmp_path / "out.y4m"
    result = run(RECV + ["-q", "-o", str(out), "--size", "64"], stdin=sent.stdout)
    assert result.returncode == 0, result.stderr.decode()
    _, count = parse_y4m(out.read_bytes())
    assert count == clip_frames()


def test_a_face_sent_by_id_needs_the_file_at_the_receiver(face_file, tmp_path):
    sent = run(SEND + [str(CLIP), "--face", str(face_file), "--face-by-id", "-q"])
    assert sent.returncode == 0, sent.stderr.decode()
    assert len(sent.stdout) < face_file.stat().st_size
    refused = run(RECV + ["-q", "-o", str(tmp_path / "a.y4m"), "--size", "64"], stdin=sent.stdout)
    assert_one_line_error(refused, "fd-recv")
    assert "--face" in refused.stderr.decode()
    accepted = run(RECV + ["-q", "-o", str(tmp_path / "b.y4m"), "--size", "64", "--face", str(face_file)],
                   stdin=sent.stdout)
    assert accepted.returncode == 0, accepted.stderr.decode()


def test_face_by_id_without_a_face_is_refused():
    result = run(SEND + [str(CLIP), "--face-by-id"])
    assert_one_line_error(result, "fd-send")


def test_every_layout_is_offered_by_the_cli():
    from facedeform.sender.analysis import LAYOUT_NAMES
    from facedeform.sender.cli import parse_args

    for layout in LAYOUT_NAMES:
        assert parse_args(["clip.mp4", "--params", layout]).params == layout


def test_bitrate_picks_a_quality_level():
    low = run(SEND + [str(CLIP), "--bitrate", "0.2", "-o", "/dev/null", "--json"])
    high = run(SEND + [str(CLIP), "--bitrate", "50", "-o", "/dev/null", "--json"])
    stats = [json.loads(r.stderr.decode().strip().splitlines()[-1]) for r in (low, high)]
    assert (stats[0]["quality"], stats[1]["quality"]) == (1, 5)
    assert stats[0]["bits_per_frame"] < stats[1]["bits_per_frame"]


@pytest.mark.parametrize("option", [["--dead-zone", "9"], ["--dead-zone", "0.1"], ["--bitrate", "0"],
                                    ["--send-every", "0"], ["--send-every", "17"], ["--redundancy", "4"]])
def test_out_of_range_rate_options_are_refused(option):
    result = run(SEND + [str(CLIP), "-o", "/dev/null", *option])
    assert_one_line_error(result, "fd-send")
    err = result.stderr.decode()
    assert option[0] in err or option[0].strip("-").replace("-", " ") in err


@pytest.mark.parametrize("both", [["--bitrate", "1", "--quality", "2"], ["--quality", "2", "--level", "3"],
                                  ["--bitrate", "4", "--level", "1"]])
def test_bitrate_quality_and_level_exclude_each_other(both):
    assert_one_line_error(run(SEND + [str(CLIP), *both]), "fd-send")


def test_a_quality_is_a_rate_and_a_level_is_not():
    from facedeform.common.errors import InputError
    from facedeform.sender.cli import parse_args
    from facedeform.sender.config import QUALITY_RATES, SendConfig

    assert list(QUALITY_RATES.values()) == sorted(QUALITY_RATES.values())
    args = parse_args(["clip.mp4", "--quality", "2"])
    assert SendConfig(quality=args.quality).bitrate == QUALITY_RATES[2] == 4000.0
    assert SendConfig(level=2).bitrate is None
    with pytest.raises(InputError, match="one of a quality, a bitrate and a level"):
        SendConfig(quality=2, bitrate=4000.0)
