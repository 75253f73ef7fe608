"""The library API (facedeform.enroll, encode, decode): the same streams and pictures as the tools."""

import gc
import io

import cv2
import numpy as np
import pytest

import facedeform
from facedeform.common.errors import BitstreamError, InputError
from facedeform.receiver.output import Y4mWriter
from tests.support import CLIP, RECV, SEND, run


def rgb_frames() -> list[np.ndarray]:
    capture, frames = cv2.VideoCapture(str(CLIP)), []
    while (got := capture.read())[0]:
        frames.append(got[1][..., ::-1])
    return frames


def test_encode_writes_what_fd_send_writes(face, tmp_path):
    path = tmp_path / "me.fdface"
    assert face.save(path) == face.id
    sent = run([*SEND, str(CLIP), "--face", str(path), "-q"])
    assert sent.returncode == 0
    assert b"".join(facedeform.encode(CLIP, face)) == sent.stdout
    assert b"".join(facedeform.encode(CLIP, str(path))) == sent.stdout
    # frames from memory (RGB) code as the file does
    assert b"".join(facedeform.encode(iter(rgb_frames()), face)) == sent.stdout


def test_an_encode_left_early_ends_its_picture_layer_quietly(face, capfd):
    chunks = facedeform.encode(CLIP, face, bitrate=4000, embed_face=False)
    next(chunks), next(chunks)  # the header and a first frame with the layer's video
    chunks.close()
    gc.collect()  # where an encoder not ended printed an error
    assert capfd.readouterr().err == ""


def test_decode_draws_what_fd_recv_draws(face, tmp_path):
    stream = b"".join(facedeform.encode(CLIP, face, embed_face=False))
    frames = list(facedeform.decode(facedeform.encode(CLIP, face, embed_face=False), face, size=(128, 96)))
    assert len(frames) == len(rgb_frames())
    assert frames[0].shape == (96, 128, 3) and frames[0].dtype == np.uint8
    ours = io.BytesIO()
    writer = Y4mWriter(ours, 25.0, (128, 96))
    for frame in frames:
        writer.write(frame)
    writer.close()
    path = tmp_path / "me.fdface"
    face.save(path)
    tool = run([*RECV, "-", "--face", str(path), "--size", "128x96", "-o", "-", "-q"], stdin=stream)
    assert tool.returncode == 0, tool.stderr
    assert ours.getvalue() == tool.stdout


def test_decode_takes_bytes_a_path_or_chunks_alike(face, tmp_path):
    stream = b"".join(facedeform.encode(CLIP, face))  # the face travels in the stream
    path = tmp_path / "talk.fd"
    path.write_bytes(stream)
    whole = [f.sum() for f in facedeform.decode(stream, size=(64, 64))]
    assert [f.sum() for f in facedeform.decode(path, size=(64, 64))] == whole
    bytewise = (stream[i:i + 1] for i in range(len(stream)))
    assert [f.sum() for f in facedeform.decode(bytewise, size=(64, 64))] == whole


def test_a_stream_cut_short_yields_its_whole_frames_then_raises(face):
    stream = b"".join(facedeform.encode(CLIP, face, embed_face=False))
    got = []
    with pytest.raises(BitstreamError, match="truncated"):
        for frame in facedeform.decode(stream[:len(stream) * 2 // 3], face, size=(64, 64)):
            got.append(frame)
    assert 10 < len(got) < len(rgb_frames())


def test_damage_is_reported_and_concealed(face):
    stream = bytearray(b"".join(facedeform.encode(CLIP, face, embed_face=False)))
    # a delta packet's check is 8 bits (protocol/framing.py): one damaged packet goes unseen once in
    # 256, so the damage spans several
    for at in range(len(stream) // 2, len(stream) // 2 + 48, 8):
        stream[at] ^= 0xFF
    reports = []
    frames = list(facedeform.decode(bytes(stream), face, size=(64, 64), on_damage=reports.append))
    assert reports and all("damaged stream" in r for r in reports)
    assert len(frames) == len(rgb_frames())


def test_caller_mistakes_are_value_and_type_errors(face):
    with pytest.raises(ValueError, match="look"):
        next(facedeform.decode(b"", look="cartoon"))
    with pytest.raises(ValueError, match="size"):
        next(facedeform.decode(b"", size=(10, 10)))
    with pytest.raises(TypeError, match="stream"):
        next(facedeform.decode(42))
    with pytest.raises(ValueError, match="uint8"):
        next(facedeform.encode([np.zeros((64, 64, 3), np.float32)]))
    with pytest.raises(ValueError, match="no frames"):
        next(facedeform.encode([]))
    with pytest.raises(ValueError, match="motion"):
        facedeform.enroll(str(CLIP), motion=-1)


def test_unusable_inputs_are_one_line_fd_errors(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        next(facedeform.encode(tmp_path / "missing.mp4"))
    with pytest.raises(BitstreamError):
        next(facedeform.decode(b"not a stream at all"))
