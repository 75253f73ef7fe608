"""fd-recv --faces: a folder of face models by id stands in for --face and keeps the ones streams carry."""

import json

import numpy as np

import facedeform
from facedeform.codec.face_file.format import Face, face_id, save_face_file
from facedeform.receiver.face_cache import FaceCache
from tests.support import CLIP, RECV, parse_y4m, run


def test_a_face_that_came_in_the_stream_is_kept_and_then_draws_a_call_sent_by_id(face, tmp_path):
    folder = tmp_path / "faces"
    in_band = b"".join(facedeform.encode(CLIP, face))
    kept = run(RECV + ["-q", "-o", str(tmp_path / "a.y4m"), "--size", "64", "--faces", str(folder)], stdin=in_band)
    assert kept.returncode == 0, kept.stderr.decode()
    assert (folder / f"{face.id}.fdface").read_bytes() == face.data
    by_id = b"".join(facedeform.encode(CLIP, face, embed_face=False))
    drawn = run(RECV + ["--json", "-o", str(tmp_path / "b.y4m"), "--size", "64", "--faces", str(folder)],
                stdin=by_id)
    assert drawn.returncode == 0, drawn.stderr.decode()
    stats = json.loads(drawn.stderr.decode().strip().splitlines()[-1])
    assert stats["face"] == "file" and stats["face_id"] == face.id and parse_y4m((tmp_path / "b.y4m").read_bytes())[1]


def test_a_file_that_is_not_the_face_its_name_says_is_not_used(face, tmp_path):
    lines: list[str] = []
    cache = FaceCache(tmp_path, None)
    data = face.data
    ident = face_id(data)
    assert cache.get(ident, lines.append) is None and not lines  # not held: no warning
    (tmp_path / f"{ident}.fdface").write_bytes(data[:-1])
    assert cache.get(ident, lines.append) is None and "not used" in lines[-1] and "\n" not in lines[-1]
    other = "0" * 64
    save_face_file(data, tmp_path / f"{other}.fdface")
    assert cache.get(other, lines.append) is None and "not the one its name says" in lines[-1]
    (tmp_path / f"{ident}.fdface").unlink()
    cache.keep(data, lines.append)
    assert np.array_equal(cache.get(ident, lines.append).vertices, Face(data).model.vertices)


def test_a_sealed_folder_keeps_faces_sealed(face, tmp_path):
    key = bytes(range(32))
    data = face.data
    FaceCache(tmp_path, key).keep(data, print)
    stored = (tmp_path / f"{face_id(data)}.fdface").read_bytes()
    assert stored != data and data not in stored
    assert FaceCache(tmp_path, key).get(face_id(data), print) is not None
