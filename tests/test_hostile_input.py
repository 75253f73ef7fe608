"""Inputs made to hurt: each is one line or one damage report, in bounded memory and time, never a
traceback, and nothing is written where it must not be."""

import os
import socket
import struct
import subprocess
import sys
import threading
import tracemalloc
import zlib
from dataclasses import replace

import numpy as np
import pytest

from facedeform.codec.face_file import format as face_file
from facedeform.codec.face_file.format import decode_face, encode_face, personal_face
from facedeform.codec.face_file.image_header import image_size
from facedeform.common.errors import BitstreamError, InputError
from facedeform.common.limits import MAX_SIDE
from facedeform.protocol.framing import varint
from facedeform.protocol.header import encode_header, parse_header
from facedeform.protocol.stream import StreamEncoder
from facedeform.receiver.transport import HeaderStore
from facedeform.receiver.viewer import MAX_CLIENTS, Viewer
from tests.support import (
    CLIP,
    RECV,
    SEND,
    a_person,
    a_picture,
    assert_one_line_error,
    header,
    run,
    smooth_tracks,
    start_listener,
    with_info,
)

ANIMATE = [sys.executable, "-m", "facedeform.receiver.animate"]


def png_header_only(width: int, height: int) -> bytes:
    """A PNG that declares ``width`` x ``height`` and carries a few rows of zeros (a bomb's head)."""
    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    rows = zlib.compress(b"\0" * (3 * width + 1) * 4)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", rows) + chunk(b"IEND", b"")


@pytest.fixture
def no_decoding(monkeypatch):
    """Fails the test if the face-file reader hands any image to the decoder."""
    def refuse(*args, **kwargs):
        raise AssertionError("an image was decoded")

    monkeypatch.setattr(face_file.cv2, "imdecode", refuse)


def with_picture_bytes(picture: bytes, width: int, height: int) -> bytes:
    """A face file whose reference picture is ``picture``, declared as ``width`` x ``height``."""
    neutral, _ = a_person()
    person = decode_face(personal_face(neutral))
    data = encode_face(replace(person, picture=a_picture()), picture_format=".png")
    start = data.index(b"\x89PNG")
    return with_info(data[:start] + picture, picture=[len(picture), width, height])


def test_image_sizes_are_read_from_headers():
    assert image_size(png_header_only(30000, 20000)) == (30000, 20000)
    assert image_size(b"GIF89a....") is None and image_size(b"") is None


@pytest.mark.parametrize("declared", [(256, 256), (MAX_SIDE, MAX_SIDE)])
def test_a_picture_bomb_is_refused_before_it_is_decoded(no_decoding, declared):
    data = with_picture_bytes(png_header_only(30000, 30000), *declared)
    with pytest.raises(InputError, match="reference picture"):
        decode_face(data)


def test_a_picture_larger_than_any_is_refused_by_its_declaration(no_decoding):
    with pytest.raises(InputError, match="reference picture of"):
        decode_face(with_picture_bytes(png_header_only(30000, 30000), 30000, 30000))


def test_a_texture_bomb_is_refused_before_it_is_decoded(no_decoding):
    neutral, _ = a_person()
    data = personal_face(neutral, np.zeros((8, 8, 3), np.uint8))
    start = data.index(b"\xff\xd8")  # the JPEG texture ends the file
    bomb = png_header_only(30000, 30000)
    data = with_info(data[:start] + bomb, texture=len(bomb))
    with pytest.raises(InputError, match="texture"):
        decode_face(data)


def test_deeply_nested_json_in_a_face_file_is_one_line():
    neutral, _ = a_person()
    data = personal_face(neutral)
    n = int.from_bytes(data[8:12], "little")
    text = b"[" * 100_000 + b"]" * 100_000
    with pytest.raises(InputError, match="unreadable description"):
        decode_face(data[:8] + len(text).to_bytes(4, "little") + text + data[12 + n:])


def test_a_bomb_in_band_is_one_line(tmp_path):
    model = with_picture_bytes(png_header_only(30000, 30000), 256, 256)
    enc = StreamEncoder(replace(header(), face_id=face_file.face_id(model), model_size=len(model)), 2, model)
    stream = enc.header() + b"".join(enc.frame(p, True) for p in smooth_tracks(10)) + enc.end()
    result = run([*RECV, "-", "-o", str(tmp_path / "out.y4m")], stdin=stream)
    assert_one_line_error(result, "fd-recv")
    assert "reference picture" in result.stderr.decode()


def test_a_bomb_as_a_preview_face_is_one_warning_and_the_face_still_comes(tmp_path):
    bomb, face = with_picture_bytes(png_header_only(30000, 30000), 256, 256), personal_face(a_person()[0])
    h = replace(header(), face_id=face_file.face_id(face), model_size=len(bomb) + len(face), preview_size=len(bomb))
    enc = StreamEncoder(h, 2, bomb + face)
    stream = enc.header() + b"".join(enc.frame(p, True) for p in smooth_tracks(10)) + enc.end()
    result = run([*RECV, "-", "-o", str(tmp_path / "out.y4m"), "--json"], stdin=stream)
    assert result.returncode == 0, result.stderr.decode()
    lines = result.stderr.decode().splitlines()
    assert sum("preview face" in line and "reference picture" in line for line in lines) == 1
    assert '"face": "stream"' in result.stderr.decode() and b"Traceback" not in result.stderr


def test_a_frame_size_beyond_the_limit_is_refused_where_the_header_is_parsed():
    body = encode_header(replace(header(), width=MAX_SIDE, height=MAX_SIDE))
    assert parse_header(body).width == MAX_SIDE
    side = varint(MAX_SIDE)
    assert len(varint(MAX_SIDE + 1)) == len(side) and body.count(side) == 2
    with pytest.raises(BitstreamError):
        parse_header(body.replace(side, varint(MAX_SIDE + 1), 1))
    with pytest.raises(ValueError, match="out of range"):  # a caller's mistake, not a stream's
        replace(header(), width=MAX_SIDE + 1)


def test_deeply_nested_animation_script_is_one_line(tmp_path):
    script = tmp_path / "deep.json"
    script.write_text("[" * 100_000)
    result = run([*ANIMATE, str(script), "-o", str(tmp_path / "a.mp4")])
    assert_one_line_error(result, "fd-animate")


def test_an_absurd_intensity_is_one_line(tmp_path):
    script = tmp_path / "s.txt"
    script.write_text("0 neutral\n1 smile 1e30\n")
    result = run([*ANIMATE, str(script), "-o", str(tmp_path / "a.mp4")])
    assert_one_line_error(result, "fd-animate")
    assert "intensity of smile" in result.stderr.decode()


def test_enroll_refuses_to_write_over_its_input(tmp_path):
    clip = tmp_path / "clip.mpg"
    clip.write_bytes(CLIP.read_bytes())
    result = run([sys.executable, "-m", "facedeform.sender.enroll", str(clip), "-o", str(clip)])
    assert_one_line_error(result, "fd-enroll")
    assert clip.read_bytes() == CLIP.read_bytes()


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full")
@pytest.mark.parametrize("prog, args", [
    ("fd-send", [*SEND, str(CLIP), "-q"]),
    ("fd-send", [*SEND, str(CLIP), "-q", "-o", "/dev/full"]),
    ("fd-animate", [*ANIMATE, "samples/animation.txt", "-o", "-"]),
    ("fd-keygen", [sys.executable, "-m", "facedeform.sender.keygen", "--force", "/dev/full"]),
])
def test_a_full_disk_is_one_line(prog, args):
    with open("/dev/full", "wb") as full:
        result = subprocess.run(args, stdout=full, stderr=subprocess.PIPE, cwd=CLIP.parents[1], timeout=300)
    assert_one_line_error(result, prog)
    assert "No space left" in result.stderr.decode()


def test_a_full_disk_for_the_receiver_is_one_line(sent):
    with open("/dev/full", "wb") as full:
        result = subprocess.run([*RECV, "-", "-o", "-", "-q"], input=sent[0], stdout=full, stderr=subprocess.PIPE,
                                timeout=300)
    assert_one_line_error(result, "fd-recv")


@pytest.mark.parametrize("argv", [["--seconds", "-1"], ["--jobs", "0"], ["--rungs", "0"]])
def test_experiment_numbers_out_of_range_are_one_line(argv):
    result = run([sys.executable, "-m", "facedeform.experiment.cli", str(CLIP), *argv])
    assert_one_line_error(result, "fd-experiment")


def test_headers_are_never_written_through_a_planted_link(tmp_path):
    store = HeaderStore(str(tmp_path))
    h = header()
    victim = tmp_path.parent / f"{tmp_path.name}-victim"
    victim.write_bytes(b"precious")
    (tmp_path / (h.ident.hex() + ".fdheader")).symlink_to(victim)
    store.keep(h)
    assert victim.read_bytes() == b"precious"
    assert [x.ident for x in store.load()] == [h.ident]


def test_planted_huge_files_links_and_fifos_are_passed_over(tmp_path):
    store = HeaderStore(str(tmp_path))
    big = tmp_path / "a.fdheader"
    with open(big, "wb") as f:
        f.truncate(3 << 30)  # 3 GB, sparse: read whole, it would take 3 GB of memory
    os.mkfifo(tmp_path / "b.fdheader")  # opened for reading the usual way, it waits for a writer forever
    (tmp_path / "c.fdheader").symlink_to(big)
    loaded: list = []
    tracemalloc.start()
    try:
        reader = threading.Thread(target=lambda: loaded.append(store.load()), daemon=True)
        reader.start()
        reader.join(timeout=60)  # a bound on a hang, not a speed: it returns at once
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert not reader.is_alive() and loaded == [[]]
    assert peak < 16 << 20


def test_the_viewer_serves_a_bounded_number_of_clients():
    viewer = Viewer("127.0.0.1:0")
    port = int(viewer.url.rstrip("/").rsplit(":", 1)[1])
    try:
        before = threading.active_count()
        idle = [socket.create_connection(("127.0.0.1", port), timeout=60) for _ in range(4 * MAX_CLIENTS)]
        for s in idle[MAX_CLIENTS:]:  # accepted in order: all slots are held, so the server closes these at once
            assert s.recv(1) == b""
        assert threading.active_count() - before <= MAX_CLIENTS
        for s in idle:
            s.close()
    finally:
        viewer.close()


def test_an_idle_connection_does_not_lock_the_sender_out(tmp_path):
    proc, port = start_listener("tcp://127.0.0.1:0", tmp_path)
    idle = socket.create_connection(("127.0.0.1", port))
    try:
        sent = run([*SEND, str(CLIP), "-q", "-o", f"tcp://127.0.0.1:{port}"])
        assert sent.returncode == 0, sent.stderr
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, err
    finally:
        idle.close()
        if proc.poll() is None:
            proc.kill()
