"""Sealed streams through the tools: fd-keygen, fd-recv --key from files, and loopback UDP under a junk flood
(with and without a key)."""

import json
import os
import socket
import stat
import time
from pathlib import Path

import numpy as np
import pytest

from facedeform.codec.face_file.format import Face, decode_face, save_face_file
from facedeform.common.errors import InputError
from facedeform.common.keys import read_key
from facedeform.protocol.secure import SecureSealer
from facedeform.protocol.secure_stream import seal_stream
from facedeform.protocol.stream import PacketEncoder, frame_bytes
from facedeform.sender.keygen import main as keygen
from tests.support import (
    DEADLINE,
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
)


@pytest.fixture
def key_file(tmp_path) -> Path:
    path = tmp_path / "call.key"
    assert keygen([str(path)]) == 0
    return path


def test_keygen_writes_a_private_key_and_never_overwrites_one(key_file, capsys):
    assert stat.S_IMODE(os.stat(key_file).st_mode) == 0o600
    text = key_file.read_text()
    assert text.startswith("# ") and len(read_key(str(key_file))) == 32
    assert keygen([str(key_file)]) == 1 and "exists" in capsys.readouterr().err
    assert keygen([str(key_file), "--force"]) == 0 and key_file.read_text() != text


def sealed_file(path, key, n=N) -> Path:
    sealed = seal_stream(SecureSealer(key), [p for p, _ in stream_packets(smooth_tracks(n))])
    path.write_bytes(frame_bytes(sealed, sealed=True))
    return path


def test_fd_recv_opens_a_sealed_file_and_reports_it(tmp_path, key_file, capsys):
    stream = sealed_file(tmp_path / "s.fd", read_key(str(key_file)), 30)
    code, err = run_main(capsys, [str(stream), "--key", str(key_file), "-o", str(tmp_path / "o.y4m"),
                                  "--size", "64", "--json"])
    stats = json.loads(err.strip().splitlines()[-1])
    assert code == 0 and stats["frames"] == 30 and stats["concealed"] == 0
    assert stats["security"]["auth_failures"] == stats["security"]["replays"] == 0
    assert stats["security"]["opened"] == stats["packets"]


def test_wrong_missing_or_malformed_keys_are_one_line(tmp_path, key_file, capsys):
    stream = sealed_file(tmp_path / "s.fd", os.urandom(32), 10)
    out = ["-o", str(tmp_path / "o.y4m")]
    assert_one_line(*run_main(capsys, [str(stream), "--key", str(key_file)] + out), "another key")
    assert_one_line(*run_main(capsys, [str(stream), "--key", str(tmp_path / "none.key")] + out), "none.key")
    bad = tmp_path / "bad.key"
    bad.write_text("not a key\n")
    assert_one_line(*run_main(capsys, [str(stream), "--key", str(bad)] + out), "bad.key", "fd-keygen")
    assert not (tmp_path / "o.y4m").exists()


def flood(datagrams: list[bytes], port: int, junk_per_second: float, interval: float, junk) -> int:
    """Sends ``datagrams`` to 127.0.0.1:``port``, one per ``interval`` seconds, and between them
    ``junk(n, i)`` datagrams (the nth, after ``datagrams[i]``) at ``junk_per_second``, in real time;
    returns the junk sent."""
    sent, start = 0, time.perf_counter()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for i, datagram in enumerate(datagrams):
            sock.sendto(datagram, ("127.0.0.1", port))
            until = start + (i + 1) * interval
            while (now := time.perf_counter()) < until and i < len(datagrams) - 1:
                while sent < (now - start) * junk_per_second:
                    sock.sendto(junk(sent, i), ("127.0.0.1", port))
                    sent += 1
                time.sleep(0.0005)
    return sent


def junk_for(sealed: list[bytes], seed: int = 7):
    """Random datagrams, the real sender's packets with a bit flipped, and replays of those sent."""
    rng = np.random.default_rng(seed)
    noise = [rng.bytes(int(rng.integers(1, 1400))) for _ in range(300)]
    flipped = []
    for packet in sealed[1:]:
        bad = bytearray(packet)
        bad[int(rng.integers(len(bad)))] ^= 1 << int(rng.integers(8))
        flipped.append(bytes(bad))
    return lambda n, i: (noise[n % len(noise)], flipped[n % len(flipped)], sealed[n % (i + 1)])[n % 3]


def test_a_junk_flood_of_2000_datagrams_a_second_leaves_every_real_frame_delivered(tmp_path, key_file):
    """The receiver reads the socket in a thread of its own and drops junk before decrypting it, so a
    flood at 2,000 datagrams a second (random bytes, forgeries, replays) costs no real frame."""
    sealed = seal_stream(SecureSealer(read_key(str(key_file))), [p for p, _ in stream_packets(smooth_tracks())])
    proc, port = start_listener("udp://127.0.0.1:0", tmp_path, "--key", str(key_file))
    junk_sent = flood(sealed, port, 2000, 0.03, junk_for(sealed))
    stats, _ = finish(proc)
    dump = np.load(tmp_path / "recv.npz")
    assert parse_y4m((tmp_path / "out.y4m").read_bytes())[1] == N
    np.testing.assert_array_equal(dump["seq"], np.arange(N))
    assert stats["frames"] == N and stats["concealed"] == 0 and stats["damage_reports"] == 0 and stats["ended"]
    security = stats["security"]
    assert security["opened"] == len(sealed) - 1 and junk_sent > 3000
    assert security["auth_failures"] + security["replays"] <= junk_sent


def test_stray_datagrams_without_a_key_cost_no_frame(tmp_path):
    """Without a key a datagram that is not ours is dropped and counted, never taken for a loss."""
    stream = [p for p, _ in stream_packets(smooth_tracks())]
    proc, port = start_listener("udp://127.0.0.1:0", tmp_path)
    rng = np.random.default_rng(3)
    strays = [rng.bytes(int(rng.integers(1, 200))) for _ in range(40)] + [b"\xfd\x40" + rng.bytes(30)]
    sent = flood(stream, port, 10, 0.02, lambda n, i: strays[n % len(strays)])
    stats, _ = finish(proc)
    dump = np.load(tmp_path / "recv.npz")
    np.testing.assert_array_equal(dump["seq"], np.arange(N))
    assert sent >= 10 and stats["skipped_bytes"] > 0
    assert stats["frames"] == N and stats["concealed"] == 0 and stats["damage_reports"] == 0 and stats["ended"]


def test_a_sealed_file_without_a_key_asks_for_one(tmp_path, capsys):
    stream = sealed_file(tmp_path / "s.fd", os.urandom(32), 10)
    assert_one_line(*run_main(capsys, [str(stream), "-o", str(tmp_path / "o.y4m")]), "--key FILE")


def test_udp_with_a_wrong_key_renders_nothing_and_says_so(tmp_path, key_file):
    sealed = seal_stream(SecureSealer(os.urandom(32)), [p for p, _ in stream_packets(smooth_tracks(20))])
    proc, port = start_listener("udp://127.0.0.1:0", tmp_path, "--key", str(key_file), "--timeout", "0.5")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for packet in sealed[:-1]:  # no end mark: the receiver waits out its timeout
            sock.sendto(packet, ("127.0.0.1", port))
    _, err = proc.communicate(timeout=DEADLINE)
    assert proc.returncode == 1 and "another key" in err.decode().strip().splitlines()[-1], err
    assert not (tmp_path / "out.y4m").exists() or not parse_y4m((tmp_path / "out.y4m").read_bytes())[1]


def test_a_face_file_sealed_at_rest_opens_only_with_its_key(tmp_path, key_file, capsys):
    key = read_key(str(key_file))
    _, data = a_face(tmp_path)
    sealed_path = tmp_path / "sealed.fdface"
    ident = save_face_file(data, sealed_path, key)
    sealed = sealed_path.read_bytes()
    assert ident == decode_face(data).content_id and data[:64] not in sealed and data[-64:] not in sealed
    assert Face.load(sealed_path, key).model.content_id == ident
    with pytest.raises(InputError, match="--key"):
        Face.load(sealed_path)
    with pytest.raises(InputError, match="another key"):
        Face.load(sealed_path, os.urandom(32))
    enc = PacketEncoder(header(ident), 2)
    packets = enc.header() + [p for x in smooth_tracks(10) for p in enc.frame(x, True)]
    stream = tmp_path / "s.fd"
    stream.write_bytes(frame_bytes(seal_stream(SecureSealer(key), packets + enc.end()), sealed=True))
    code, err = run_main(capsys, [str(stream), "--key", str(key_file), "--face", str(sealed_path),
                                  "-o", str(tmp_path / "o.y4m"), "--size", "64", "--json"])
    assert code == 0 and json.loads(err.strip().splitlines()[-1])["face"] == "file"


def test_tcp_carries_a_sealed_stream(tmp_path, key_file):
    sealed = seal_stream(SecureSealer(read_key(str(key_file))), [p for p, _ in stream_packets(smooth_tracks())])
    proc, port = start_listener("tcp://127.0.0.1:0", tmp_path, "--key", str(key_file))
    with socket.create_connection(("127.0.0.1", port), timeout=DEADLINE) as sock:
        sock.sendall(frame_bytes(sealed, sealed=True))
    stats, _ = finish(proc)
    assert stats["frames"] == N and stats["concealed"] == 0 and stats["security"]["opened"] == len(sealed) - 1
