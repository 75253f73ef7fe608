"""Face model files: round trip, ids that name the content, and one-line refusals of bad files."""

import hashlib
from dataclasses import replace

import numpy as np
import pytest

from codec.deform import PAPER_PARAMS, Deformer
from common.errors import InputError
from codec.face_file import decode_face, encode_face, load_face_file, personal_face, save_face_file
from codec.face_model import load_base_face

BASE = load_base_face()
GENERIC_ID = "29d964b2735ca5b817cf688586b0cdcbe7dae01b01573aa45c8ce855b3d3a966"


def a_person(seed=0):
    """(468, 3) landmarks of a made-up person in arbitrary units and offset, and a texture."""
    rng = np.random.default_rng(seed)
    neutral = (BASE.vertices * [1.1, 1.0, 0.9] + rng.normal(0, 0.004, BASE.vertices.shape)) * 7.0 + 3.0
    y, x = np.mgrid[0:64, 0:64]
    texture = np.dstack([4 * x, 4 * y, 128 + 60 * np.sin(x / 5.0 + seed)]).astype(np.uint8)
    return neutral, texture


def test_the_generic_face_keeps_its_id_and_has_no_texture():
    assert BASE.content_id == GENERIC_ID
    assert BASE.texture is None


def test_round_trip_keeps_mesh_texture_and_features(tmp_path):
    neutral, texture = a_person()
    data = personal_face(neutral, texture)
    ident = save_face_file(data, tmp_path / "p.fdface")
    face = load_face_file(tmp_path / "p.fdface")
    assert face.content_id == ident == hashlib.sha256(data).hexdigest()
    assert face.texture.shape == (64, 64, 3) and face.texture.dtype == np.uint8
    assert np.abs(face.texture.astype(int) - texture).mean() < 3  # JPEG: close, not exact
    np.testing.assert_array_equal(face.faces, BASE.faces)
    np.testing.assert_allclose(face.uv, BASE.uv, atol=1e-6)
    assert face.feature_points == BASE.feature_points and face.meta == BASE.meta
    np.testing.assert_array_equal(face.mouth_faces, BASE.mouth_faces)
    Deformer(face).deform(np.r_[10.0, np.zeros(len(PAPER_PARAMS) - 1)])  # works unchanged


def test_vertices_are_normalised_like_the_base_face():
    neutral, _ = a_person()
    face = decode_face(personal_face(neutral))
    lo, hi = face.vertices.min(axis=0), face.vertices.max(axis=0)
    np.testing.assert_allclose(face.vertices[10, 1] - face.vertices[152, 1], 1.0, atol=1e-6)
    np.testing.assert_allclose((lo + hi) / 2, 0.0, atol=1e-6)
    assert not np.allclose(face.vertices, BASE.vertices, atol=1e-3)
    assert face.texture is None


def test_id_is_stable_and_changes_with_content():
    neutral, texture = a_person()
    first = personal_face(neutral, texture)
    assert personal_face(neutral, texture) == first
    assert decode_face(first).content_id == decode_face(first).content_id
    other, _ = a_person(seed=1)
    ids = {decode_face(d).content_id for d in (first, personal_face(other, texture), personal_face(neutral))}
    assert len(ids) == 3 and GENERIC_ID not in ids


def test_png_texture_is_exact():
    neutral, texture = a_person()
    face = decode_face(personal_face(neutral, texture))
    again = decode_face(encode_face(replace(face, texture=texture), ".png"))
    np.testing.assert_array_equal(again.texture, texture)


def _corrupt(data: bytes, where: int) -> bytes:
    return data[:where] + bytes([data[where] ^ 0xFF]) + data[where + 1:]


@pytest.mark.parametrize("mangle, message", [
    (lambda d: b"", "no FDFACE mark"),
    (lambda d: b"GIF89a" + d[6:], "no FDFACE mark"),
    (lambda d: d[:6] + bytes([9]) + d[7:], "version 9"),
    (lambda d: d[:-10], "length does not match"),
    (lambda d: _corrupt(d, 20), "unreadable description"),
    (lambda d: d.replace(b"\xff\xd8\xff", b"\0\0\0"), "texture is not"),
])
def test_bad_files_are_refused_in_one_line(tmp_path, mangle, message):
    neutral, texture = a_person()
    path = tmp_path / "bad.fdface"
    path.write_bytes(mangle(personal_face(neutral, texture)))
    with pytest.raises(InputError, match=message) as info:
        load_face_file(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_missing_file_and_directory_are_refused(tmp_path):
    with pytest.raises(InputError, match="cannot read"):
        load_face_file(tmp_path / "nothing.fdface")
    with pytest.raises(InputError, match="not a file"):
        load_face_file(tmp_path)
