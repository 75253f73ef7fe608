"""Face model files: round trip, ids that name the content, and one-line refusals of bad files."""

import hashlib
import json
import lzma
from dataclasses import replace

import numpy as np
import pytest

from facedeform.codec.face_file.format import (
    _PACKING,
    BUDGET,
    COARSEST_CRF,
    HD_BUDGET,
    MESH_STEPS,
    Face,
    decode_face,
    described,
    encode_face,
    personal_face,
    save_face_file,
    within_budget,
)
from facedeform.codec.model.deform import Deformer
from facedeform.codec.render.picture import Placement
from facedeform.common.errors import InputError
from facedeform.common.parameters import PAPER_PARAMS
from tests.support import (
    BASE,
    a_person,
    a_picture,
    a_picture_with_a_mouth,
    a_picture_with_shut_eyes,
    as_version,
    with_info,
)

GENERIC_ID = "29d964b2735ca5b817cf688586b0cdcbe7dae01b01573aa45c8ce855b3d3a966"


def test_the_generic_face_keeps_its_id_and_has_no_texture():
    assert BASE.content_id == GENERIC_ID
    assert BASE.texture is None


def test_round_trip_keeps_mesh_texture_and_features(tmp_path):
    neutral, texture = a_person()
    data = personal_face(neutral, texture)
    ident = save_face_file(data, tmp_path / "p.fdface")
    face = Face.load(tmp_path / "p.fdface").model
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
    step = 1 / MESH_STEPS  # what the file keeps of a coordinate
    np.testing.assert_allclose(face.vertices[10, 1] - face.vertices[152, 1], 1.0, atol=step)
    np.testing.assert_allclose((lo + hi) / 2, 0.0, atol=step)
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
    (lambda d: d[:6] + bytes([11]) + d[7:], "version 11"),
    (lambda d: d[:-10], "length does not match"),
    (lambda d: _corrupt(d, 20), "unreadable description"),
    (lambda d: d.replace(b"\xff\xd8\xff", b"\0\0\0"), "texture is not"),
])
def test_bad_files_are_refused_in_one_line(tmp_path, mangle, message):
    neutral, texture = a_person()
    path = tmp_path / "bad.fdface"
    path.write_bytes(mangle(personal_face(neutral, texture)))
    with pytest.raises(InputError, match=message) as info:
        Face.load(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_missing_file_and_directory_are_refused(tmp_path):
    with pytest.raises(InputError, match="cannot read"):
        Face.load(tmp_path / "nothing.fdface")
    with pytest.raises(InputError, match="not a file"):
        Face.load(tmp_path)


def test_the_reference_picture_round_trips():
    neutral, texture = a_person()
    picture = a_picture()
    face = decode_face(personal_face(neutral, texture, picture=picture))
    np.testing.assert_array_equal(face.picture.projection, picture.projection)
    assert face.picture.image.shape == (80, 96, 3)
    assert np.abs(face.picture.image.astype(int) - picture.image).mean() < 4  # AV1: close, not exact
    lossless = decode_face(encode_face(face, picture_format=".png"))
    np.testing.assert_array_equal(lossless.picture.image, face.picture.image)
    assert decode_face(personal_face(neutral, texture)).picture is None


def test_files_of_older_versions_are_still_read():
    from facedeform.codec.model.motion_basis import MotionBasis

    neutral, texture = a_person()
    motion = MotionBasis(np.array([100, 101, 102]), np.random.default_rng(3).normal(0, 0.1, (2, 3, 3)))
    person = decode_face(personal_face(neutral, texture, motion=motion, picture=a_picture()))
    data = encode_face(replace(person, picture=replace(person.picture, ring_weights=np.full(144, 0.5))))
    now = decode_face(data)
    for version in (1, 2, 3, 4, 5, 6, 7, 8):
        kept = data if version > 1 else personal_face(neutral, texture)
        old = decode_face(as_version(kept, version))
        np.testing.assert_allclose(old.vertices, now.vertices, atol=1e-6)  # as <f4 held them
        assert old.meta == BASE.meta
        assert old.picture is None if version < 3 else (old.picture.ring_weights is None) == (version == 3)
        np.testing.assert_array_equal(old.texture, decode_face(kept).texture)
        if version > 1:  # the <i1 patterns as the older floats held them
            np.testing.assert_allclose(old.motion.vectors, now.motion.vectors, rtol=1e-3, atol=1e-12)
    np.testing.assert_array_equal(now.picture.image, decode_face(as_version(data, 3)).picture.image)


def test_a_picture_replaces_the_texture_and_the_generic_features_take_no_bytes():
    from facedeform.codec.render.picture import face_texture

    neutral, texture = a_person()
    with_texture = personal_face(neutral, texture, picture=a_picture())
    data = personal_face(neutral, None, picture=a_picture())
    face = decode_face(data)
    assert face.texture is None and face.meta == BASE.meta
    assert len(as_version(with_texture, 3)) - len(data) > 10_000  # the feature points and the texture
    image, uv = face_texture(face)
    assert image is face.picture.image
    # uv (v up) puts every vertex where the picture's projection does
    pixels = np.column_stack([face.vertices, np.ones(len(face.vertices))]) @ face.picture.projection.T
    np.testing.assert_allclose(uv * [96, -80] + [0, 80], pixels[:, :2], atol=1e-9)
    assert face_texture(decode_face(with_texture))[0].shape == (64, 64, 3)  # its own texture first


def test_ring_weights_round_trip_and_must_fit_the_face():
    neutral, texture = a_person()
    person = decode_face(personal_face(neutral, None, picture=a_picture()))
    weights = np.linspace(0.0, 1.0, 144)
    data = encode_face(replace(person, picture=replace(person.picture, ring_weights=weights)))
    np.testing.assert_allclose(decode_face(data).picture.ring_weights, weights, atol=0.5 / 255)
    older = as_version(data, 6)  # the weights in the JSON, where any value can be written
    for rings in ([1] * 143, [256] * 144, [-1] * 144, "x", [[1, 2]] * 72, [float("inf")] * 144):
        with pytest.raises(InputError) as info:
            decode_face(with_info(older, rings=rings), "me.fdface")
        assert "\n" not in str(info.value) and str(info.value).startswith("me.fdface: ")
    for count in (143, 5000, -1, "x"):  # version 7: their count
        with pytest.raises(InputError) as info:
            decode_face(with_info(data, rings=count), "me.fdface")
        assert "\n" not in str(info.value) and str(info.value).startswith("me.fdface: ")


def _projection(scale=40.0, shift=(48.0, -40.0, 0.0), rotation=None):
    return Placement(scale, np.eye(3) if rotation is None else rotation, np.array(shift)).matrix().tolist()


@pytest.mark.parametrize("changes, message", [
    ({"projection": [[float("nan")] * 4] * 3}, "not a finite 3x4"),
    ({"projection": [[1, 2, 3]]}, "not a finite 3x4"),
    ({"projection": "up"}, "unreadable description"),
    ({"projection": _projection(rotation=np.diag([1.0, 2.0, 1.0]))}, "not a rotation and scale"),
    ({"projection": _projection(scale=0.5)}, "out of the picture"),
    ({"projection": _projection(scale=1e6)}, "out of the picture"),
    ({"projection": _projection(shift=(1e5, 0, 0))}, "out of the picture"),
    ({"picture": [None, 96, 80]}, "unreadable description"),
    ({"picture": [10, 96, 80]}, "length does not match"),
    ({"picture": [-1, 96, 80]}, "reference picture of"),
    ({"picture": "x"}, "unreadable description"),
    ({"picture": [0, 96, 80, 5]}, "unreadable description"),
])
def test_hostile_picture_fields_are_refused_in_one_line(changes, message):
    neutral, texture = a_person()
    data = personal_face(neutral, texture, picture=a_picture())
    if "projection" in changes:  # in the JSON before version 7
        data = as_version(data, 6)
    with pytest.raises(InputError, match=message) as info:
        decode_face(with_info(data, **changes), "me.fdface")
    assert "\n" not in str(info.value) and str(info.value).startswith("me.fdface: ")


@pytest.mark.parametrize("projection, message", [
    ([[float("nan")] * 4] * 3, "not a finite 3x4"),
    (_projection(rotation=np.diag([1.0, 2.0, 1.0])), "not a rotation and scale"),
    (_projection(scale=1e6), "out of the picture"),
])
def test_a_hostile_packed_projection_is_refused_in_one_line(projection, message):
    """Version 7 packs the projection (the last 96 bytes before the images when there are no rings
    or open mouth): its numbers are checked as the JSON's were."""
    neutral, texture = a_person()
    data = personal_face(neutral, texture, picture=a_picture())
    n = int.from_bytes(data[8:12], "little")
    size = json.loads(data[12:12 + n])["packed"]
    raw = lzma.decompress(data[12 + n:12 + n + size], lzma.FORMAT_RAW, filters=_PACKING)
    packed = lzma.compress(raw[:-96] + np.asarray(projection, "<f8").tobytes(), lzma.FORMAT_RAW, filters=_PACKING)
    hostile = with_info(data[:12 + n] + packed + data[12 + n + size:], packed=len(packed))
    with pytest.raises(InputError, match=message) as info:
        decode_face(hostile, "me.fdface")
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("size, message", [((97, 80), "not a 97x80"), ((96, 8), "reference picture of 96x8"),
                                           ((5000, 80), "reference picture of 5000x80")])
def test_a_picture_of_another_size_than_declared_is_refused(size, message):
    neutral, texture = a_person()
    data = personal_face(neutral, texture, picture=a_picture())
    n = int.from_bytes(data[8:12], "little")
    picture_bytes = json.loads(data[12:12 + n])["picture"][0]
    with pytest.raises(InputError, match=message):
        decode_face(with_info(data, picture=[picture_bytes, *size]))


def test_a_damaged_picture_is_refused():
    neutral, texture = a_person()
    data = personal_face(neutral, texture, picture=a_picture())
    at = len(data) - described(data)["picture"][0]
    for damaged in (_corrupt(data, at), data[:at] + bytes(len(data) - at), data[:at + 4] + bytes(len(data) - at - 4)):
        with pytest.raises(InputError, match="reference picture is not"):
            decode_face(damaged)


def test_an_av1_picture_larger_than_declared_is_refused_before_it_is_drawn():
    """AV1 has no header that image_size reads: the decoder is told the declared size's pixels and
    refuses a larger frame before allocating it."""
    neutral, texture = a_person()
    small = personal_face(neutral, texture, picture=a_picture())
    large = personal_face(neutral, texture, picture=a_picture(1024, 1024))
    picture = large[len(large) - described(large)["picture"][0]:]
    at = len(small) - described(small)["picture"][0]
    hostile = with_info(small[:at] + picture, picture=[len(picture), 96, 80])
    with pytest.raises(InputError, match="reference picture is not a 96x80"):
        decode_face(hostile)


def test_the_open_mouth_round_trips():
    neutral, texture = a_person()
    picture = a_picture_with_a_mouth()
    person = replace(decode_face(personal_face(neutral, texture)), picture=picture)
    face = decode_face(encode_face(person, picture_format=".png"))
    np.testing.assert_array_equal(face.picture.mouth, picture.mouth)
    np.testing.assert_allclose(face.picture.mouth_points, picture.mouth_points)


@pytest.mark.parametrize("side, budget", [(256, BUDGET), (800, HD_BUDGET)])
def test_a_face_over_its_budget_takes_a_coarser_picture_and_keeps_its_parts(side, budget):
    """fd-enroll's face file: a picture of plain gradients as it is; one of noise, which no CRF brings
    within the budget, at COARSEST_CRF and no coarser; the open mouth stays as it was either way."""
    neutral, texture = a_person()
    person = replace(decode_face(personal_face(neutral, texture)), picture=a_picture_with_a_mouth())
    assert within_budget(person) == encode_face(person)
    rng = np.random.default_rng(0)
    detail = replace(person.picture, image=np.kron(rng.integers(0, 256, (side // 4, side // 4, 3)),
                                                   np.ones((4, 4, 1))).astype(np.uint8))
    busy = replace(person, picture=detail)
    assert len(encode_face(busy)) > budget
    data = within_budget(busy)
    assert data == encode_face(busy, picture_quality=COARSEST_CRF) and len(data) > budget
    got = decode_face(data).picture
    np.testing.assert_array_equal(got.mouth, decode_face(encode_face(busy)).picture.mouth)
    assert got.image.shape == detail.image.shape


def test_a_face_still_over_its_budget_drops_its_motion_basiss_last_patterns():
    """At COARSEST_CRF and still over, the basis loses its last patterns (those that explained least)
    one by one while over, down to LEAST_PATTERNS; the patterns kept are stored as before."""
    from facedeform.codec.face_file.format import LEAST_PATTERNS
    from facedeform.codec.model.motion_basis import MotionBasis

    rng = np.random.default_rng(1)
    vertices = np.arange(0, 468, 2)
    vectors = rng.uniform(-1, 1, (12, len(vertices), 3))
    person = replace(decode_face(personal_face(*a_person())), picture=a_picture_with_a_mouth(),
                     motion=MotionBasis(vertices, vectors, steps=np.full(12, 127)))
    coarse = [len(encode_face(replace(person, motion=replace(person.motion, vectors=vectors[:k],
                                                             steps=np.full(k, 127))), picture_quality=COARSEST_CRF))
              for k in (12, 11, 10)]
    assert coarse[0] > coarse[1] > coarse[2]
    kept = decode_face(within_budget(person, budget=coarse[1])).motion
    whole = decode_face(encode_face(person)).motion
    assert len(kept.vectors) == 11 and np.array_equal(kept.vectors, whole.vectors[:11])
    assert len(decode_face(within_budget(person, budget=1000)).motion.vectors) == LEAST_PATTERNS
    assert len(decode_face(within_budget(person, budget=coarse[0])).motion.vectors) == 12


@pytest.mark.parametrize("changes, message", [
    ({"mouth_points": [[1.0, 1.0]] * 3}, "open mouth's points do not fit"),
    ({"mouth_points": [[100.0, 1.0]] * 20}, "open mouth's points do not fit"),
    ({"mouth_points": [[float("inf"), 1.0]] * 20}, "open mouth's points do not fit"),
    ({"mouth": [10, 500, 10]}, "open mouth of 500x10"),
    ({"mouth": [-5, 16, 10]}, "open mouth of 16x10"),
])
def test_hostile_open_mouth_fields_are_refused_in_one_line(changes, message):
    neutral, texture = a_person()
    data = personal_face(neutral, texture, picture=a_picture_with_a_mouth())
    if "mouth_points" in changes:  # in the JSON before version 7
        data = as_version(data, 6)
    with pytest.raises(InputError, match=message) as info:
        decode_face(with_info(data, **changes), "me.fdface")
    assert "\n" not in str(info.value)


def test_the_shut_eyes_round_trip_and_are_read_from_version_9():
    neutral, texture = a_person()
    person = replace(decode_face(personal_face(neutral, texture)), picture=a_picture_with_shut_eyes())
    data = encode_face(person, picture_format=".png")
    for face in (decode_face(data), decode_face(as_version(data, 9))):
        assert face.picture.shut_eyes_at == (20, 30)
        np.testing.assert_array_equal(face.picture.shut_eyes, person.picture.shut_eyes)
        np.testing.assert_array_equal(face.picture.mouth, person.picture.mouth)
    without = encode_face(replace(person, picture=replace(person.picture, shut_eyes=None, shut_eyes_at=None)))
    assert decode_face(without).picture.shut_eyes is None


@pytest.mark.parametrize("changes, message", [
    ({"shut_eyes": [10, 30, 12, 80, 30]}, r"shut eyes of 30x12 pixels at \(80, 30\)"),  # past the picture's edge
    ({"shut_eyes": [10, 30, 12, -1, 30]}, "shut eyes of 30x12"),
    ({"shut_eyes": [10, 0, 12, 20, 30]}, "shut eyes of 0x12"),
    ({"shut_eyes": [10, 30, 13, 20, 30]}, "shut eyes is not a 30x13"),  # not the image's own size
    ({"shut_eyes": [-5, 30, 12, 20, 30]}, "shut eyes of 30x12"),
])
def test_hostile_shut_eyes_are_refused_in_one_line(changes, message):
    neutral, texture = a_person()
    person = replace(decode_face(personal_face(neutral, texture)), picture=a_picture_with_shut_eyes())
    data = encode_face(person, picture_format=".png")
    size = json.loads(data[12:12 + int.from_bytes(data[8:12], "little")])["shut_eyes"][0]
    changes["shut_eyes"][0] = changes["shut_eyes"][0] if changes["shut_eyes"][0] < 0 else size
    with pytest.raises(InputError, match=message) as info:
        decode_face(with_info(data, **changes), "me.fdface")
    assert "\n" not in str(info.value)


def test_version_6_keeps_only_what_a_receiver_cannot_derive():
    """The generic topology and uv are named, not stored; the vertices are steps from the generic
    face's, within half a step of the fitted ones; the rest is packed."""
    from facedeform.codec.model.face_model import normalise

    neutral, _ = a_person()
    data = personal_face(neutral, None, picture=a_picture())
    info = json.loads(data[12:12 + int.from_bytes(data[8:12], "little")])
    assert info["uv"] == info["topology"] == "base"
    assert len(as_version(data, 5)) - len(data) > 10_000  # uv, triangles and float vertices
    face = decode_face(data)
    np.testing.assert_array_equal(face.faces, BASE.faces)
    np.testing.assert_array_equal(face.uv, BASE.uv)
    assert np.abs(face.vertices - normalise(neutral)).max() <= 0.5 / MESH_STEPS + 1e-12
    lossless = encode_face(face, picture_format=".png")
    assert encode_face(decode_face(lossless), picture_format=".png") == lossless  # what it stores, exactly


def test_a_mesh_in_coarser_steps_round_trips_and_hostile_steps_are_refused():
    """A preview's mesh (preview_face) is stored in its own steps, and says so."""
    neutral, _ = a_person()
    face = decode_face(personal_face(neutral, None, picture=a_picture()))
    coarse = encode_face(face, mesh_steps=256)
    assert np.abs(decode_face(coarse).vertices - face.vertices).max() <= 0.5 / 256 + 1e-12
    assert len(coarse) < len(encode_face(face)) - 300
    for steps in (0, 15, 1 << 17, "x"):
        with pytest.raises(InputError) as info:
            decode_face(with_info(coarse, mesh=steps), "me.fdface")
        assert "\n" not in str(info.value)


def test_a_face_of_its_own_topology_and_uv_stores_them():
    neutral, texture = a_person()
    face = decode_face(personal_face(neutral, texture))
    own = replace(face, uv=face.uv * 0.5, faces=face.faces[:, ::-1].copy())
    again = decode_face(encode_face(own))
    np.testing.assert_array_equal(again.faces, own.faces)
    np.testing.assert_allclose(again.uv, own.uv, atol=1e-7)


def _packed_span(data: bytes) -> tuple[int, int]:
    n = int.from_bytes(data[8:12], "little")
    return 12 + n, json.loads(data[12:12 + n])["packed"]


@pytest.mark.parametrize("mangle, message", [
    (lambda d, at, size: d[:at + size // 2] + bytes([d[at + size // 2] ^ 0x55]) + d[at + size // 2 + 1:],
     "(damaged mesh|mesh does not match|out of range)"),
    (lambda d, at, size: with_info(d, packed=size + 5), "length does not match"),
    (lambda d, at, size: with_info(d, packed=-1), "length does not match"),
    (lambda d, at, size: with_info(d, topology="base", faces=5), "triangles"),
    (lambda d, at, size: with_info(d, uv="own"), "mesh does not match"),
])
def test_a_damaged_or_hostile_packed_mesh_is_one_line(mangle, message):
    neutral, texture = a_person()
    data = personal_face(neutral, texture)
    with pytest.raises(InputError, match=message) as info:
        decode_face(mangle(data, *_packed_span(data)), "me.fdface")
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("seed", range(8))
def test_a_coded_mesh_and_basis_of_any_bytes_is_a_face_or_one_line(seed):
    """Arithmetic-coded integers have no invalid code: any bytes decode, in bounded time, to a mesh and
    basis that are either within their bounds or refused in one line."""
    from facedeform.codec.model.motion_basis import MotionBasis

    neutral, texture = a_person()
    motion = MotionBasis(np.arange(468), np.random.default_rng(3).normal(0, 0.1, (2, 468, 3)))
    data = personal_face(neutral, texture, motion=motion)
    at, size = sum(_packed_span(data)), described(data)["coded"]
    junk = np.random.default_rng(seed).integers(0, 256, size, dtype=np.uint8).tobytes()
    try:
        face = decode_face(data[:at] + junk + data[at + size:], "me.fdface")
    except InputError as error:
        assert "\n" not in str(error) and str(error).startswith("me.fdface: ")
    else:
        assert np.all(np.abs(face.vertices) < 10) and np.all(np.abs(face.motion.vectors) <= 1)
    with pytest.raises(InputError, match="length does not match"):
        decode_face(with_info(data, coded=size + 1))


def test_a_packed_mesh_is_never_inflated_past_its_declared_size():
    """A small packed section of zeros that would inflate to megabytes stops at the declared size."""
    import lzma

    from facedeform.codec.face_file.format import _PACKING

    neutral, texture = a_person()
    data = personal_face(neutral, texture)
    at, size = _packed_span(data)
    bomb = lzma.compress(bytes(64 << 20), lzma.FORMAT_RAW, filters=_PACKING)
    assert len(bomb) < 20_000
    hostile = with_info(data[:at] + bomb + data[at + size:], packed=len(bomb))
    with pytest.raises(InputError, match="mesh does not match"):
        decode_face(hostile)
