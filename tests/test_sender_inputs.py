"""fd-send's inputs and outputs: image sequences, cameras, --neutral, --json, TCP and UDP on loopback."""

import json
import socket
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest

from facedeform.codec.model.face_model import load_base_face
from facedeform.codec.render.eyelids import LIDS
from facedeform.protocol.stream import DatagramDecoder, Frame, StreamDecoder
from facedeform.sender.calibrate import LOWER_LIP, choose_rest, eye_opening, lip_gap
from tests.support import CLIP, SEND, assert_one_line_error, run

FRAMES = 30


@pytest.fixture(scope="module")
def image_dir(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("frames")
    cap = cv2.VideoCapture(str(CLIP))
    for i in range(FRAMES):
        ok, frame = cap.read()
        assert ok
        cv2.imwrite(str(folder / f"{i + 1:04d}.png"), frame)
    return folder


def frames_in(stream: bytes) -> int:
    decoder = StreamDecoder()
    events = decoder.feed(stream) + decoder.close()
    return sum(isinstance(e, Frame) for e in events)


@pytest.mark.parametrize("form", ["directory", "pattern"])
def test_image_sequence(image_dir, form, tmp_path):
    spec = str(image_dir) if form == "directory" else str(image_dir / "%04d.png")
    result = run(SEND + [spec, "--fps", "30", "--json"])
    assert result.returncode == 0, result.stderr.decode()
    stats = json.loads(result.stderr)
    assert stats["frames"] == FRAMES and stats["fps"] == 30.0
    assert frames_in(result.stdout) == FRAMES


def test_neutral_picks_that_frame(tmp_path):
    dump = tmp_path / "d.npz"
    result = run(SEND + [str(CLIP), "--neutral", "40", "--json", "--dump", str(dump), "-o", str(tmp_path / "s.fd")])
    assert result.returncode == 0, result.stderr.decode()
    assert json.loads(result.stderr)["rest_frame"] == 40
    data = np.load(dump)
    assert int(data["rest_frame"]) == 40
    # the rest frame's face is the rest face: its pose-free target is the base face itself
    np.testing.assert_allclose(data["targets"][40], load_base_face().vertices, atol=1e-5)


def test_default_rest_face_is_in_the_first_second():
    result = run(SEND + [str(CLIP), "--json", "-o", "/dev/null"])
    assert result.returncode == 0
    assert 0 <= json.loads(result.stderr)["rest_frame"] < 25


def test_the_rest_frame_is_not_a_blink_even_where_its_mouth_is_the_most_closed():
    """Lids measured from shut eyes would draw every open eye of the call wider than it is."""
    face = load_base_face()
    pixels = face.vertices * [200.0, -200.0, 200.0] + [128.0, 128.0, 0.0]
    talking, blinking = pixels.copy(), pixels.copy()
    talking[LOWER_LIP, 1] += 4.0  # lips a little apart
    blinking[LOWER_LIP, 1] += 1.0  # lips nearer together, but the eyes shut
    for upper, lower in LIDS:
        blinking[upper] = blinking[lower]
    candidates = [(3, blinking, blinking), (7, talking, talking)]
    assert lip_gap(blinking) < lip_gap(talking) and eye_opening(blinking) < 0.1 * eye_opening(talking)
    assert choose_rest(candidates) == 7
    assert choose_rest(candidates, neutral=3) == 3  # asked for, it is taken


@pytest.mark.parametrize("args, message", [
    (["--camera", "99"], "camera 99 not available"),
    ([str(CLIP), "-o", "tcp://127.0.0.1:1"], "cannot connect"),
    ([str(CLIP), "--neutral", "500"], "no face tracked in that frame"),
    (["/nonexistent/%04d.png"], "no images found"),
])
def test_input_errors_are_one_line(args, message):
    result = run(SEND + args)
    assert_one_line_error(result, "fd-send")
    assert message in result.stderr.decode()


@pytest.mark.parametrize("args, message", [
    (["--bitrate", "nan"], "out of range"),
    (["--smoothing", "inf"], "out of range"),
    (["--fps", "-1"], "out of range"),
    (["--fps", "0"], "out of range"),
    (["--fps", "nan"], "out of range"),
    (["--quality", "9"], "out of range"),
    (["--level", "0"], "out of range"),
    (["--send-every", "x"], "not an integer"),
])
def test_absurd_numbers_are_refused_before_any_work(args, message):
    result = run(SEND + [str(CLIP), "-o", "/dev/null", *args])
    assert result.returncode == 2 and message in result.stderr.decode()
    assert len(result.stderr.decode().strip().splitlines()) == 1


def test_output_paths_are_checked_before_the_work(tmp_path):
    own = tmp_path / "talk.mpg"
    own.write_bytes(CLIP.read_bytes())
    result = run(SEND + [str(own), "-o", str(own)])
    assert_one_line_error(result, "fd-send")
    assert "is the input" in result.stderr.decode()
    assert own.read_bytes() == CLIP.read_bytes()  # untouched
    for option in ("-o", "--dump"):
        other = ["-o", "/dev/null"] if option == "--dump" else []
        result = run(SEND + [str(CLIP), option, str(tmp_path / "missing" / "x"), *other])
        assert_one_line_error(result, "fd-send")
        assert "does not exist" in result.stderr.decode()


def test_the_session_refuses_settings_out_of_range():
    from facedeform.common.errors import InputError
    from facedeform.sender.config import LIMITS, SendConfig

    for name, (lo, hi) in LIMITS.items():
        with pytest.raises(InputError, match=name.replace("_", " ")):
            SendConfig(**{name: lo - 1})
        if hi is not None:
            with pytest.raises(InputError):
                SendConfig(**{name: float("nan") if isinstance(hi, float) else hi + 1})
    with pytest.raises(InputError, match="layout"):
        SendConfig(layout="nonsense")


@pytest.mark.parametrize("rule", ["paper", "refined"])
def test_the_rule_fitted_to_is_named_in_the_header(rule):
    result = run(SEND + [str(CLIP), "--params", "paper", "--rule", rule, "-q"])
    assert result.returncode == 0, result.stderr.decode()
    decoder = StreamDecoder()
    decoder.feed(result.stdout)
    assert decoder.header.rule == rule and (decoder.header.width, decoder.header.height) == (360, 288)


def test_tcp_loopback():
    server = socket.create_server(("127.0.0.1", 0))
    received = bytearray()

    def accept():
        conn, _ = server.accept()
        with conn:
            while chunk := conn.recv(65536):
                received.extend(chunk)

    thread = threading.Thread(target=accept)
    thread.start()
    result = run(SEND + [str(CLIP), "-q", "-o", f"tcp://127.0.0.1:{server.getsockname()[1]}"])
    thread.join(timeout=60)
    server.close()
    assert result.returncode == 0, result.stderr.decode()
    assert frames_in(bytes(received)) == 75


def test_udp_loopback():
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    sock.settimeout(1.0)  # everything is queued by the time fd-send exits
    result = run(SEND + [str(CLIP), "-q", "-o", f"udp://127.0.0.1:{sock.getsockname()[1]}"])
    assert result.returncode == 0, result.stderr.decode()
    decoder, frames = DatagramDecoder(), 0
    try:
        while True:
            frames += sum(isinstance(e, Frame) for e in decoder.receive(sock.recv(65536)))
    except TimeoutError:
        pass
    sock.close()
    assert frames == 75
