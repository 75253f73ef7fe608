"""fd-recv as people use it: UDP with loss, TCP, face models, and every mistake as one line.

Sockets are on loopback only; every wait has a deadline.
"""

import json
import socket

import numpy as np
import pytest

from facedeform.codec.face_file.format import decode_face
from facedeform.protocol.stream import PacketEncoder, frame_bytes
from tests.support import (
    DEADLINE,
    GENERIC,
    KEY,
    N,
    a_face,
    assert_one_line,
    finish,
    header,
    parse_y4m,
    run_main,
    smooth_tracks,
    start_listener,
    stream_packets,
    write_stream,
)


def test_udp_with_five_percent_loss_gives_every_frame_and_resyncs(tmp_path):
    params = smooth_tracks()
    stream = stream_packets(params)
    frame_packets = [i for i, (_, frames) in enumerate(stream) if frames is not None]
    dropped = set(frame_packets[7::20])  # a deterministic 5 % of the frame packets
    concealed = set()
    for i in dropped:
        first, last = stream[i][1]
        concealed.update(range(first, -(-(last + 1) // KEY) * KEY))  # until the next keyframe
    proc, port = start_listener("udp://127.0.0.1:0", tmp_path)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for i, (packet, _) in enumerate(stream):
            if i not in dropped:
                sock.sendto(packet, ("127.0.0.1", port))
    stats, _ = finish(proc)
    dump = np.load(tmp_path / "recv.npz")
    assert len(dropped) >= 3
    assert parse_y4m((tmp_path / "out.y4m").read_bytes())[1] == N
    np.testing.assert_array_equal(dump["seq"], np.arange(N))
    assert set(np.flatnonzero(dump["concealed"])) == concealed
    enc, sent = PacketEncoder(header()), []  # what the sender's encoder says the receiver shows
    for p in params:
        enc.frame(p, True)
        sent.append(enc.reconstruction)
    good = ~dump["concealed"]
    np.testing.assert_allclose(dump["params"][good], np.array(sent)[good], atol=1e-9)
    assert stats["frames"] == stats["written"] == N and stats["concealed"] == len(concealed)
    assert stats["ended"] and stats["damage_reports"] == len(dropped)
    assert 0 <= stats["latency_ms"]["median"] <= stats["latency_ms"]["max"]


def test_udp_without_an_end_mark_ends_after_the_idle_timeout(tmp_path):
    stream = stream_packets(smooth_tracks(50))[:-1]
    proc, port = start_listener("udp://127.0.0.1:0", tmp_path, "--timeout", "0.5")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for packet, _ in stream:
            sock.sendto(packet, ("127.0.0.1", port))
    stats, lines = finish(proc)
    assert stats["frames"] == 50 and not stats["ended"]
    assert any("without the stream's end mark" in line for line in lines)


def test_tcp_delivers_every_frame(tmp_path):
    stream = stream_packets(smooth_tracks())
    proc, port = start_listener("tcp://127.0.0.1:0", tmp_path)
    with socket.create_connection(("127.0.0.1", port), timeout=DEADLINE) as sock:
        sock.sendall(frame_bytes([p for p, _ in stream]))
    stats, _ = finish(proc)
    assert parse_y4m((tmp_path / "out.y4m").read_bytes())[1] == N
    assert stats["frames"] == N and stats["concealed"] == 0 and stats["ended"] and stats["face"] == "generic"


def test_face_file_for_another_stream_is_refused_naming_both_ids(tmp_path, capsys):
    face, data = a_face(tmp_path)
    stream = write_stream(tmp_path / "s.fd")
    code, err = run_main(capsys, [str(stream), "--face", str(face), "-o", str(tmp_path / "o.y4m")])
    assert_one_line(code, err, decode_face(data).content_id[:12], GENERIC.content_id[:12])


@pytest.mark.parametrize("in_band", [False, True])
def test_personal_face_from_file_or_in_band_is_drawn_textured(tmp_path, capsys, in_band):
    face, data = a_face(tmp_path)
    ident = decode_face(data).content_id
    stream = write_stream(tmp_path / "s.fd", ident, data if in_band else b"")
    args = [str(stream), "-o", str(tmp_path / "o.y4m"), "--size", "64", "--json", "--fps", "50"]
    code, err = run_main(capsys, args + ([] if in_band else ["--face", str(face)]))
    stats = json.loads(err.strip().splitlines()[-1])
    assert code == 0 and stats["face"] == ("stream" if in_band else "file") and stats["face_id"] == ident
    assert stats["written"] == 60 == parse_y4m((tmp_path / "o.y4m").read_bytes())[1]


def test_stream_for_an_unknown_face_asks_for_it(tmp_path, capsys):
    stream = write_stream(tmp_path / "s.fd", "ab" * 32)
    code, err = run_main(capsys, [str(stream), "-o", str(tmp_path / "o.y4m")])
    assert_one_line(code, err, "--face FILE")


@pytest.mark.parametrize("kind", [socket.SOCK_DGRAM, socket.SOCK_STREAM])
def test_port_in_use(capsys, kind):
    with socket.socket(socket.AF_INET, kind) as taken:
        taken.bind(("127.0.0.1", 0))
        if kind == socket.SOCK_STREAM:
            taken.listen(1)
        scheme = "udp" if kind == socket.SOCK_DGRAM else "tcp"
        url = f"{scheme}://127.0.0.1:{taken.getsockname()[1]}"
        code, err = run_main(capsys, ["--listen", url, "-o", "unused.y4m", "-q"])
    assert_one_line(code, err, "cannot listen", url)


def test_a_terminal_is_pointed_to_a_file_or_the_browser(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr("sys.stdout.isatty", lambda: True)
    code, err = run_main(capsys, [str(write_stream(tmp_path / "s.fd"))])
    assert_one_line(code, err, "--serve", "-o FILE.mp4")


@pytest.mark.parametrize("args, words", [
    (["missing.fd"], ["missing.fd", "cannot read"]),
    (["--face", "missing.fdface"], ["missing.fdface"]),
    (["--listen", "http://x:1"], ["udp://HOST:PORT"]),
    (["--bogus"], ["--bogus"]),
    (["--fps", "0"], ["--fps"]),
])
def test_user_mistakes_are_one_line(tmp_path, capsys, args, words):
    code, err = run_main(capsys, args + ["-o", str(tmp_path / "o.y4m")])
    assert_one_line(code, err, *words)


def test_corrupted_and_foreign_input_are_one_line(tmp_path, capsys):
    junk = tmp_path / "junk.fd"
    junk.write_bytes(bytes(range(256)) * 300)
    code, err = run_main(capsys, [str(junk), "-o", str(tmp_path / "o.y4m")])
    assert_one_line(code, err, "not an fd stream")
    cut = write_stream(tmp_path / "s.fd")
    cut.write_bytes(cut.read_bytes()[:-20])
    code, err = run_main(capsys, [str(cut), "-o", str(tmp_path / "o.y4m"), "-q"])
    assert_one_line(code, err, "truncated")


def test_look_face_without_a_texture_says_it_draws_shaded(tmp_path, capsys):
    code, err = run_main(capsys, [str(write_stream(tmp_path / "s.fd")), "--look", "face", "-o",
                                  str(tmp_path / "o.y4m"), "--size", "64", "-q"])
    assert code == 0 and "drawn shaded" in err
