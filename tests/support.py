"""What several test modules share: paths, running the tools, stream fixtures, output parsing.

Plain helpers, imported by the tests (``from tests.support import ...``); pytest's fixtures and
markers are in conftest.py.
"""

import json
import lzma
import selectors
import subprocess
import sys
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from facedeform.codec.face_file.format import (
    _PACKING,
    PATTERN_SCALE,
    VERTEX_STEPS,
    _differences,
    _stored_order,
    decode_face,
    personal_face,
    save_face_file,
)
from facedeform.codec.model.face_model import ReferencePicture, load_base_face, mouth_vertices
from facedeform.codec.render.picture import Placement
from facedeform.common.parameters import PAPER_PARAMS
from facedeform.protocol.stream import (
    Datagrams,
    Header,
    PacketEncoder,
    StreamDecoder,
    StreamEncoder,
    frame_bytes,
    steps_for,
)
from facedeform.receiver.cli import main
from facedeform.receiver.session import ReceiveSession
from facedeform.sender import picture_layer

ROOT = Path(__file__).resolve().parents[1]
CLIP = ROOT / "samples" / "grid_bbaf2n.mpg"
SEND = [sys.executable, "-m", "facedeform.sender.cli"]
RECV = [sys.executable, "-m", "facedeform.receiver.cli"]


def run(args, stdin=None, **kw):
    return subprocess.run(args, input=stdin, capture_output=True, cwd=ROOT, timeout=300, **kw)


def clip_frames() -> int:
    cap = cv2.VideoCapture(str(CLIP))
    n = 0
    while cap.read()[0]:
        n += 1
    return n


def assert_one_line_error(result, prog):
    err = result.stderr.decode()
    assert result.returncode != 0
    assert "Traceback" not in err
    assert err.startswith(f"{prog}: ") and err.count("\n") == 1, err


def coded_error(stream: bytes, decoded: np.ndarray, meant: np.ndarray):
    """(the stream's header, (n, k) |decoded - meant| along the header's coded axes, in steps)."""
    decoder = StreamDecoder()
    decoder.feed(stream)
    h = decoder.header
    return h, np.abs(np.array([h.coordinates(d) - h.coordinates(m) for d, m in zip(decoded, meant)]))


def parse_y4m(data: bytes):
    header, _, rest = data.partition(b"\n")
    fields = dict((f[:1], f[1:]) for f in header.split(b" ")[1:])
    assert header.startswith(b"YUV4MPEG2 ")
    w, h = int(fields[b"W"]), int(fields[b"H"])
    frame_bytes = w * h * 3 // 2
    count = 0
    while rest:
        assert rest.startswith(b"FRAME\n")
        rest = rest[6 + frame_bytes:]
        count += 1
    return fields, count

# streams of the paper's set with head rotation, for the receiver's tests
NAMES = PAPER_PARAMS + ("rx", "ry", "rz")
N, FPS, KEY = 150, 25.0, 25
DEADLINE = 120  # seconds: generous for a loaded machine, never reached when things work
GENERIC = load_base_face()


def smooth_tracks(n=N) -> np.ndarray:
    """(n, 16) parameters that move like speech: jaw in degrees, mouth points in face units, head in degrees."""
    t = np.arange(n)[:, None] / FPS
    phase = np.arange(len(NAMES))[None, :]
    scale = np.array([8.0] + [0.02] * 12 + [4.0] * 3)
    return scale * (0.5 + 0.5 * np.sin(2 * np.pi * (1.5 + 0.1 * phase) * t + phase))


def header(face_id=GENERIC.content_id, model_size=0) -> Header:
    return Header(FPS, NAMES, steps_for(NAMES), face_id, key_interval=KEY, model_size=model_size)


def stream_packets(params, fpp=2):
    """The stream as datagrams: [(packet, (first, last) frame it carries, or None)], header to end mark."""
    enc = PacketEncoder(header(), fpp)
    out = [(p, None) for p in enc.header()]
    first = 0
    for i, p in enumerate(params):
        for packet in enc.frame(p, True):
            out.append((packet, (first, i)))
            first = i + 1
    *last, end = enc.end()
    out += [(p, (first, len(params) - 1)) for p in last] + [(end, None)]
    return out


def stream_datagrams(params, copies=1, header_every=0, eager=0, sealer=None) -> tuple[list[bytes], list[np.ndarray]]:
    """(datagrams, what the encoder says the receiver shows for each frame) of a stream at 2 frames per packet."""
    enc = PacketEncoder(header(), 2)
    head = enc.header()
    pack = Datagrams(head[0], copies, header_every, eager, sealer)
    out = ([sealer.preamble()] if sealer else []) + pack.add(head)
    sent = []
    for x in params:
        out += pack.add(enc.frame(x, True))
        sent.append(enc.reconstruction)
    return out + pack.add(enc.end()), sent


def start_listener(url, tmp_path, *extra):
    proc = subprocess.Popen(RECV + ["--listen", url, "-o", str(tmp_path / "out.y4m"), "--size", "64",
                                    "--dump", str(tmp_path / "recv.npz"), "--json", *extra],
                            stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, cwd=ROOT, bufsize=0)
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stderr, selectors.EVENT_READ)
        if not sel.select(timeout=DEADLINE):
            proc.kill()
            pytest.fail("fd-recv did not start listening")
    line = proc.stderr.readline().decode()
    assert line.startswith("fd-recv: listening on "), line
    return proc, int(line.rsplit(":", 1)[1])


def finish(proc):
    _, err = proc.communicate(timeout=DEADLINE)
    lines = err.decode().strip().splitlines()
    assert proc.returncode == 0, err.decode()
    return json.loads(lines[-1]), lines[:-1]


def a_face(tmp_path) -> tuple[Path, bytes]:
    bent = GENERIC.vertices * [1.1, 1.0, 1.0]
    texture = np.full((64, 64, 3), (180, 140, 120), np.uint8)
    data = personal_face(bent, texture)
    path = tmp_path / "p.fdface"
    save_face_file(data, path)
    return path, data


def write_stream(path, face_id=GENERIC.content_id, model=b"", n=30) -> Path:
    enc = StreamEncoder(header(face_id, len(model)), 2, model)
    path.write_bytes(enc.header() + b"".join(enc.frame(p, True) for p in smooth_tracks(n)) + enc.end())
    return path


def run_main(capsys, args):
    try:
        code = main(args)
    except SystemExit as exc:  # argparse
        code = exc.code
    return code, capsys.readouterr().err


def assert_one_line(code, err, *words):
    assert code != 0 and err.startswith("fd-recv: ") and err.count("\n") == 1, err
    for w in words:
        assert w in err, err


# face files, for the face-file reader's tests
BASE = GENERIC


def a_picture(w=96, h=80):
    """A textured (h, w, 3) picture and a projection putting the normalised face in its middle."""
    y, x = np.mgrid[0:h, 0:w]
    image = np.dstack([x * 2, y * 3, 100 + 50 * np.sin(x / 4.0)]).astype(np.uint8)
    return ReferencePicture(image, Placement(40.0, np.eye(3), np.array([w / 2, -h / 2, 0.0])).matrix())


def a_person(seed=0):
    """(468, 3) landmarks of a made-up person in arbitrary units and offset, and a texture."""
    rng = np.random.default_rng(seed)
    neutral = (BASE.vertices * [1.1, 1.0, 0.9] + rng.normal(0, 0.004, BASE.vertices.shape)) * 7.0 + 3.0
    y, x = np.mgrid[0:64, 0:64]
    texture = np.dstack([4 * x, 4 * y, 128 + 60 * np.sin(x / 5.0 + seed)]).astype(np.uint8)
    return neutral, texture

def as_version(data: bytes, version: int) -> bytes:
    """A current face file rewritten as an older version (1-9) would have held it: before version 10
    the vertices as <i2 steps of 1/VERTEX_STEPS, the motion basis's vertices as <u2 and its steps'
    differences modulo 256, all packed (version 9 with shut eyes, 8 without); the motion basis's
    patterns as <i1 of 127 steps each before version 8; the picture's
    numbers (projection, ring weights, open mouth's points) in the JSON before version 7; vertices,
    uv and triangles written out in full before version 6; the motion basis's patterns as <f2 in
    version 4; before it the feature points written out, the patterns as <f4, no ring weights;
    before 3, no picture; before 2, no motion basis."""
    if data[6] == 10:
        data = _as_version_9(data)
    if version >= 8:
        assert version == data[6], "a face with shut eyes was version 9, one without version 8"
        return data
    n = int.from_bytes(data[8:12], "little")
    info = json.loads(data[12:12 + n])
    k, c, _ = info.get("motion", (0, 0, ""))
    packed = info.pop("packed")
    raw = lzma.decompress(data[12 + n:12 + n + packed], lzma.FORMAT_RAW, filters=_PACKING)
    vertices = BASE.vertices + np.frombuffer(raw, "<i2", 3 * info["vertices"]).reshape(-1, 3) / VERTEX_STEPS
    at = 6 * info["vertices"]
    uv = BASE.uv if info.get("uv") == "base" else np.frombuffer(raw, "<f4", 2 * info["vertices"], at)
    at += 0 if uv is BASE.uv else 8 * info["vertices"]
    faces = BASE.faces if info.get("topology") == "base" else np.frombuffer(raw, "<u2", 3 * info["faces"], at)
    at += 0 if faces is BASE.faces else 6 * info["faces"]
    motion_end = at + 2 * k + c + 3 * c * k if k else at
    # version 7's motion basis: the indices, then each pattern's coordinates in 127 steps for 1
    motion7 = raw[at:at + 2 * k] + np.rint(decode_face(data).motion.vectors * PATTERN_SCALE).astype("<i1").tobytes() \
        if k else b""
    if version == 7:
        repacked = lzma.compress(raw[:at] + motion7 + raw[motion_end:], lzma.FORMAT_RAW, filters=_PACKING)
        info["packed"] = len(repacked)
        text = json.dumps(info).encode()
        return data[:6] + bytes([7, 0]) + len(text).to_bytes(4, "little") + text + repacked + data[12 + n + packed:]
    if "picture" in info:  # version 7's numbers, after the motion basis, back into the JSON
        info["projection"] = np.frombuffer(raw, "<f8", 12, motion_end).reshape(3, 4).tolist()
        rings, points = info.pop("rings", None), info.pop("mouth_points", None)
        if rings is not None:
            info["rings"] = np.frombuffer(raw, "u1", rings, motion_end + 96).astype(int).tolist()
        if points is not None:
            info["mouth_points"] = np.frombuffer(raw, "<f4", 2 * points, motion_end + 96 + (rings or 0)).reshape(
                -1, 2).astype(float).tolist()
    if version == 6:
        repacked = lzma.compress(raw[:at] + motion7, lzma.FORMAT_RAW, filters=_PACKING)
        info["packed"] = len(repacked)
        text = json.dumps(info).encode()
        return data[:6] + bytes([6, 0]) + len(text).to_bytes(4, "little") + text + repacked + data[12 + n + packed:]
    info.pop("uv", None), info.pop("topology", None)
    mesh = b"".join(np.ascontiguousarray(a, dtype=t).tobytes() for a, t in ((vertices, "<f4"), (uv, "<f4"),
                                                                            (faces, "<u2")))
    patterns = np.frombuffer(motion7, "<i1", 3 * c * k, 2 * k)
    if version < 5:
        patterns = (patterns / PATTERN_SCALE).astype("<f2" if version == 4 else "<f4")
    motion = motion7[:2 * k] + patterns.tobytes()
    images = data[12 + n + packed:]
    if version < 4:
        if info["meta"] == "base":
            info["meta"] = BASE.meta
        info.pop("rings", None)
    if version < 3:
        for field in ("picture", "projection", "mouth", "mouth_points"):
            info.pop(field, None)
        images = images[:info["texture"]]
    assert version >= 2 or not k
    text = json.dumps(info).encode()
    return data[:6] + bytes([version, 0]) + len(text).to_bytes(4, "little") + text + mesh + motion + images


def _as_version_9(data: bytes) -> bytes:
    """A version 10 face file as version 8 or 9 held it."""
    n = int.from_bytes(data[8:12], "little")
    info = json.loads(data[12:12 + n])
    packed, coded = info.pop("packed"), info.pop("coded")
    raw = lzma.decompress(data[12 + n:12 + n + packed], lzma.FORMAT_RAW, filters=_PACKING)
    face = decode_face(data)
    own = (0 if info.get("uv") == "base" else 8 * info["vertices"]) + (0 if info.get("topology") == "base"
                                                                       else 6 * info["faces"])
    motion = b""
    if face.motion is not None:
        steps = face.motion.steps
        values = np.rint(face.motion.vectors * steps[:, None, None]).astype(np.int64)
        differences = _differences(values, _stored_order(face.motion.vertices, face.faces)) % 256
        motion = face.motion.vertices.astype("<u2").tobytes() + steps.astype("u1").tobytes() \
            + differences.astype("u1").tobytes()
    vertices = np.rint((face.vertices - BASE.vertices) * VERTEX_STEPS).astype("<i2").tobytes()
    c = info.get("motion", (0, 0))[1]
    repacked = lzma.compress(vertices + raw[:own] + motion + raw[own + c:], lzma.FORMAT_RAW, filters=_PACKING)
    info["packed"] = len(repacked)
    text = json.dumps(info).encode()
    version = 9 if "shut_eyes" in info else 8
    return data[:6] + bytes([version, 0]) + len(text).to_bytes(4, "little") + text + repacked \
        + data[12 + n + packed + coded:]


def with_info(data: bytes, **changes) -> bytes:
    """The file with its JSON description changed (and its length field kept right)."""
    n = int.from_bytes(data[8:12], "little")
    info = json.loads(data[12:12 + n])
    info.update(changes)
    text = json.dumps(info).encode()
    return data[:8] + len(text).to_bytes(4, "little") + text + data[12 + n:]

def a_picture_with_a_mouth():
    mouth = np.full((10, 16, 3), 200, np.uint8)
    points = np.linspace([1.0, 1.0], [15.0, 9.0], len(mouth_vertices(BASE)))
    return replace(a_picture(), mouth=mouth, mouth_points=points)


def a_picture_with_shut_eyes():
    """A picture with an open mouth and shut eyes (face file version 9)."""
    shut = np.dstack([np.full((12, 30), 90), np.tile(np.arange(30) * 5, (12, 1)), np.full((12, 30), 40)])
    return replace(a_picture_with_a_mouth(), shut_eyes=shut.astype(np.uint8), shut_eyes_at=(20, 30))


@contextmanager
def sender_pictures():
    """The sender's own picture of every frame (what its picture layer reconstructs), as a list
    filled while the context lasts, each as soon as the sender knows it (PictureLayer.pictures)."""
    pictures: list[np.ndarray] = []
    step, close = picture_layer.PictureLayer.step, picture_layer.PictureLayer.close

    def stepped(self, *args, **kwargs):
        out = step(self, *args, **kwargs)
        pictures.extend(image.copy() for _, image in self.pictures())
        return out

    def closed(self):
        pictures.extend(image.copy() for _, image in self.pictures(final=True))
        close(self)

    picture_layer.PictureLayer.step, picture_layer.PictureLayer.close = stepped, closed
    try:
        yield pictures
    finally:
        picture_layer.PictureLayer.step, picture_layer.PictureLayer.close = step, close


def received(events: list, face) -> list[np.ndarray]:
    """What fd-recv draws of a stream's decoded ``events`` with ``face`` (a BaseFace), in frame order:
    its session's pictures, each frame drawn once the picture layer lets it (header.ahead)."""
    from facedeform.api import _Collect

    pictures: list[np.ndarray] = []
    session = ReceiveSession(lambda fps, size: [_Collect(pictures)], None, face, warn=lambda line: None)
    session.handle(events, 0.0)
    session.close()
    return pictures


def datagrams_per_frame(session, receive=lambda datagram: None) -> np.ndarray:
    """A SendSession over datagrams run to its end, each datagram (the header's first) handed to ``receive``:
    the bits of each frame's datagrams after the header, the end's counted with the last frame."""
    bits: list[int] = []
    for i, datagrams in enumerate(session.packets()):
        for datagram in datagrams:
            receive(datagram)
        if i:  # after the header
            bits += [0] * (session.frame_count - len(bits))
            bits[-1] += 8 * sum(map(len, datagrams))
    return np.array(bits)


def largest_window(bits, fps: float = 25.0) -> float:
    """bit/s of the costliest 2 seconds of ``bits`` (each frame's): what a rate is kept within, over any 2 s."""
    window = round(2.0 * fps)
    assert len(bits) >= window, "a call shorter than its window"
    return float(np.convolve(bits, np.ones(window), mode="valid").max()) / 2.0


def sent_per_frame(session) -> tuple[list[bytes], np.ndarray, list[list[bytes]]]:
    """A SendSession run to its end: (the stream's chunks, the header's first; the bits of each frame's
    packets after the header, the end mark's counted with the last frame; the packets of each chunk)."""
    chunks, bits, lists = [], [], []
    for packets in session.packets():
        if not packets:
            continue
        chunks.append(frame_bytes(packets, session.sealed))
        lists.append(packets)
        if len(chunks) > 1:
            bits += [0] * (session.frame_count - len(bits))
            bits[-1] += 8 * len(chunks[-1])
    return chunks, np.array(bits), lists
