"""The personal motion basis: learning, the face file, the deformation, the sender's fit and the CLIs."""

import dataclasses
import json
import lzma
import subprocess
import sys

import numpy as np
import pytest

from facedeform.codec.face_file.format import _PACKING, Face, _groups, decode_face, described, encode_face
from facedeform.codec.model.deform import Deformer
from facedeform.codec.model.face_model import load_base_face
from facedeform.codec.model.motion_basis import MotionBasis, learn_basis
from facedeform.common.errors import InputError
from facedeform.common.parameters import (
    BASIS_PARAMS,
    BODY_PARAMS,
    EXTENDED_PARAMS,
    GLOBAL_PARAMS,
    LID_PARAMS,
    MAX_COMPONENTS,
    PAPER_PARAMS,
    POSE_PARAMS,
    slots,
)
from facedeform.protocol.arith import decode_integers, encode_integers
from facedeform.protocol.quantise import DEAD_ZONE
from facedeform.sender.fit import ModelFit
from facedeform.sender.motion import FRAMES_PER_PATTERN, learn_motion
from tests.support import CLIP, ROOT, as_version, coded_error, with_info

RNG = np.random.default_rng(7)


def planted(n=200, k=30, m=3, noise=1e-4):
    """Residuals made of m known patterns over k vertices, plus a little noise."""
    patterns = RNG.normal(size=(m, k, 3))
    coeffs = RNG.normal(size=(n, m)) * [0.05, 0.03, 0.01][:m]
    residuals = np.einsum("nm,mkd->nkd", coeffs, patterns) + noise * RNG.normal(size=(n, k, 3))
    return residuals, np.arange(100, 100 + k), patterns


def test_learning_recovers_the_planted_patterns_scaled_to_a_unit_vertex_move():
    residuals, vertices, patterns = planted()
    basis = learn_basis(residuals, vertices, 3)
    assert basis.names == BASIS_PARAMS[:3]
    np.testing.assert_allclose(np.linalg.norm(basis.vectors, axis=2).max(axis=1), 1.0)
    q, _ = np.linalg.qr(basis.vectors.reshape(3, -1).T)  # the learned span holds every planted pattern
    for p in patterns.reshape(3, -1):
        assert np.linalg.norm(p - q @ (q.T @ p)) < 1e-2 * np.linalg.norm(p)
    again = learn_basis(residuals.copy(), vertices, 3)
    np.testing.assert_array_equal(again.vectors, basis.vectors)  # signs are fixed: same data, same file


def test_learning_refuses_more_patterns_than_allowed_or_frames():
    residuals, vertices, _ = planted(n=4)
    with pytest.raises(InputError):
        learn_basis(residuals, vertices, 5)
    with pytest.raises(InputError):
        learn_basis(planted(n=40)[0], vertices, MAX_COMPONENTS + 1)


def _face_with_basis():
    residuals, vertices, _ = planted()
    return dataclasses.replace(load_base_face(), motion=learn_basis(residuals, vertices, 3))


def test_face_file_carries_the_basis_and_old_files_still_read():
    face = _face_with_basis()
    data = encode_face(face)
    back = decode_face(data)
    assert back.motion.over == face.motion.over
    np.testing.assert_array_equal(back.motion.vertices, face.motion.vertices)
    # stored in each pattern's steps: within half a step of each coordinate
    assert np.all(np.abs(back.motion.vectors - face.motion.vectors) <= 0.5 / face.motion.steps[:, None, None] + 1e-12)
    plain = encode_face(load_base_face())
    assert decode_face(plain).motion is None
    assert decode_face(as_version(plain, 1)).motion is None  # version 1 had no motion section


def _damaged(raw: bytes) -> bytes:
    """``raw`` with the basis's first vertex index (100, beside 101) made 9999."""
    start = raw.index(np.asarray([100, 101], "<u2").tobytes())
    return raw[:start] + np.asarray([9999], "<u2").tobytes() + raw[start + 2:]


def test_a_damaged_basis_is_refused():
    data = encode_face(_face_with_basis())
    with pytest.raises(InputError, match="motion basis"):
        decode_face(_damaged(as_version(data, 5)))
    older = as_version(data, 8)  # the indices packed
    n = int.from_bytes(older[8:12], "little")
    at, size = 12 + n, json.loads(older[12:12 + n])["packed"]
    packed = lzma.compress(_damaged(lzma.decompress(older[at:at + size], lzma.FORMAT_RAW, filters=_PACKING)),
                           lzma.FORMAT_RAW, filters=_PACKING)
    with pytest.raises(InputError, match="motion basis"):
        decode_face(with_info(older[:at] + packed + older[at + size:], packed=len(packed)))
    info = described(data)  # version 10: the indices coded, each as its step from the one before
    at, size = len(data) - info["coded"], info["coded"]
    groups, count = _groups(info["vertices"], info["motion"][1], info["motion"][0])
    values = decode_integers(data[at:at + size], groups, count)
    for first in (9999 + 1, -5):
        values[3 * info["vertices"]] = first
        coded = encode_integers(values, groups, count)
        with pytest.raises(InputError, match="motion basis"):
            decode_face(with_info(data[:at] + coded, coded=len(coded)))


def test_each_pattern_is_stored_as_finely_as_its_coefficients_need():
    from facedeform.codec.model.motion_basis import LEAST_STEPS, MOST_STEPS, REACH_STEPS

    residuals, vertices, _ = planted()
    residuals = residuals * 0.1  # coefficients of about 0.015, 0.009 and 0.003 face heights at most
    basis = learn_basis(residuals, vertices, 3)
    coefficients = np.linalg.lstsq(basis.vectors.reshape(3, -1).T, residuals.reshape(len(residuals), -1).T,
                                   rcond=None)[0]
    reach = np.abs(coefficients).max(axis=1)
    np.testing.assert_array_equal(basis.steps, np.clip(np.ceil(REACH_STEPS * reach), LEAST_STEPS, MOST_STEPS))
    assert basis.steps.max() < MOST_STEPS  # coarser than a file stored every pattern before
    face = dataclasses.replace(load_base_face(), motion=basis)
    data = encode_face(face)
    back = decode_face(data).motion
    np.testing.assert_array_equal(back.steps, basis.steps)
    error = np.abs(back.vectors - basis.vectors).max(axis=(1, 2))
    assert np.all(error <= 0.5 / basis.steps + 1e-12)
    assert np.all(reach * error <= 0.5 / REACH_STEPS)  # at the largest coefficient
    assert encode_face(dataclasses.replace(face, motion=back)) == data  # what it stores, stored again the same
    finest = encode_face(dataclasses.replace(face, motion=dataclasses.replace(basis, steps=None)))
    assert len(finest) > len(data)


def _with_motion_bytes(data: bytes, change) -> bytes:
    """The face file with its packed mesh and basis changed by ``change(raw, start of the basis)``."""
    n = int.from_bytes(data[8:12], "little")
    at, size = 12 + n, json.loads(data[12:12 + n])["packed"]
    raw = bytearray(lzma.decompress(data[at:at + size], lzma.FORMAT_RAW, filters=_PACKING))
    change(raw, bytes(raw).index(np.asarray([100, 101], "<u2").tobytes()))
    packed = lzma.compress(bytes(raw), lzma.FORMAT_RAW, filters=_PACKING)
    return with_info(data[:at] + packed + data[at + size:], packed=len(packed))


@pytest.mark.parametrize("where, value", [(60, 0), (60, 200), (63, 100)])  # a step count; a vertex past its steps
def test_a_basis_with_impossible_steps_is_refused(where, value):
    residuals, vertices, _ = planted()
    data = encode_face(dataclasses.replace(load_base_face(), motion=learn_basis(residuals * 0.1, vertices, 3)))

    def change(raw, start):
        raw[start + where] = value

    with pytest.raises(InputError, match="motion basis out of range"):
        decode_face(_with_motion_bytes(as_version(data, 8), change))
    info = described(data)  # version 10: the step counts packed first, the differences coded
    at, size = len(data) - info["coded"] - info["packed"], info["packed"]
    raw = bytearray(lzma.decompress(data[at:at + size], lzma.FORMAT_RAW, filters=_PACKING))
    groups, count = _groups(info["vertices"], 3, info["motion"][0])
    values = decode_integers(data[at + size:], groups, count)
    if where == 60:
        raw[0] = value
    else:
        values[3 * info["vertices"] + info["motion"][0]] = value
    packed = lzma.compress(bytes(raw), lzma.FORMAT_RAW, filters=_PACKING)
    coded = encode_integers(values, groups, count)
    with pytest.raises(InputError, match="motion basis out of range"):
        decode_face(with_info(data[:at] + packed + coded, packed=len(packed), coded=len(coded)))


def test_coefficients_move_exactly_the_basis_vertices():
    face = _face_with_basis()
    deformer = Deformer(face)
    params = np.zeros(len(EXTENDED_PARAMS))
    rest = deformer.deform_extended(params)
    params[EXTENDED_PARAMS.index("basis_1")] = 0.02
    moved = deformer.deform_extended(params)
    np.testing.assert_allclose(moved[face.motion.vertices] - rest[face.motion.vertices],
                               0.02 * face.motion.vectors[1], atol=1e-12)
    others = np.setdiff1d(np.arange(len(rest)), face.motion.vertices)
    np.testing.assert_array_equal(moved[others], rest[others])
    params[:] = 0
    params[EXTENDED_PARAMS.index("basis_5")] = 0.5  # past the face's three patterns: nothing
    np.testing.assert_array_equal(deformer.deform_extended(params), rest)


def test_the_fit_recovers_coefficients_of_what_the_paper_model_leaves_over():
    base = load_base_face()
    fit = ModelFit(Deformer(base))
    lower = fit.lower
    shapes = []
    for _ in range(60):  # random lower-face shapes; their paper-fit residuals teach the basis
        t = base.vertices.copy()
        t[lower] += 0.01 * RNG.normal(size=(len(lower), 3))
        shapes.append(t[lower] - fit.lower_mesh(fit.paper(t)))
    face = dataclasses.replace(base, motion=learn_basis(np.stack(shapes), lower, 4, "paper"))
    fit = ModelFit(Deformer(face))
    paper = np.zeros(len(PAPER_PARAMS))
    paper[[0, 2, 11]] = [6.0, 0.01, -0.008]
    coeffs = np.array([0.03, -0.02, 0.01, 0.005])
    params = np.zeros(len(EXTENDED_PARAMS))
    params[:len(PAPER_PARAMS)] = paper
    params[slots(face.motion.names)] = coeffs
    targets = Deformer(face).blend(params)  # a basis learned from noise folds the skin: before the guard
    got_paper = fit.paper(targets)
    got = fit.motion(targets, got_paper)
    np.testing.assert_allclose(got, coeffs, atol=0.1 * np.abs(coeffs).max())
    assert abs(got_paper[0] - paper[0]) < 0.5


def _run(cmd):
    return subprocess.run([sys.executable, "-m", *cmd], capture_output=True, cwd=ROOT, timeout=300)


@pytest.mark.slow
@pytest.mark.parametrize("over", ["rest", "paper"])
def test_enrol_then_send_the_personal_layout_end_to_end(tmp_path, over):
    face = tmp_path / "me.fdface"
    enrolled = _run(["facedeform.sender.enroll", str(CLIP), "-o", str(face), "--motion", "4", "--motion-over", over])
    assert enrolled.returncode == 0, enrolled.stderr.decode()
    assert f"motion basis of 4 patterns over the {over}" in enrolled.stderr.decode()
    model = Face.load(face).model
    assert (model.motion.components, model.motion.over) == (4, over)
    stream = tmp_path / "s.fd"
    params = ["--params", "personal"] if over == "paper" else []  # the default for a face with a basis
    sent = _run(["facedeform.sender.cli", str(CLIP), "--face", str(face), *params, "--level", "3",  # dead zone fixed
                 "-o", str(stream), "--dump", str(tmp_path / "sent.npz"), "-q"])
    assert sent.returncode == 0, sent.stderr.decode()
    got = _run(["facedeform.receiver.cli", str(stream), "-o", str(tmp_path / "out.y4m"), "--size", "64",
                "--dump", str(tmp_path / "recv.npz"), "-q"])
    assert got.returncode == 0, got.stderr.decode()
    recv = np.load(tmp_path / "recv.npz")
    paper = PAPER_PARAMS if over == "paper" else ()
    # and where the head is in the picture, and how the picture moves if it has a background to show it
    expected = paper + BASIS_PARAMS[:4] + LID_PARAMS + POSE_PARAMS
    extras = ((), GLOBAL_PARAMS, BODY_PARAMS, GLOBAL_PARAMS + BODY_PARAMS)
    assert tuple(recv["names"]) in (expected + extra for extra in extras)
    cols = slice(len(paper), len(paper) + 4)
    coeffs = recv["params"][:, cols]
    assert np.abs(coeffs).max() > 0.002  # the basis is used, frame by frame
    header, error = coded_error(stream.read_bytes(), recv["params"], np.load(tmp_path / "sent.npz")["params"])
    assert header.basis is None  # the motion basis is decorrelated already: no coding basis on top
    assert np.all(error <= DEAD_ZONE * (1 + 1e-9))  # within the encoder's dead zone


def test_a_short_clip_gets_as_many_patterns_as_its_frames_teach():
    residual = np.random.default_rng(0).normal(size=(4 * FRAMES_PER_PATTERN - 1, 6, 3))
    assert learn_motion(residual, np.arange(6), 12).components == 3
    assert learn_motion(residual[:FRAMES_PER_PATTERN - 1], np.arange(6), 12) is None


def test_a_clip_too_short_for_one_pattern_gives_a_face_without_a_basis_and_personal_then_refuses(tmp_path):
    face = tmp_path / "me.fdface"
    enrolled = _run(["facedeform.sender.enroll", str(CLIP), "-o", str(face), "--motion", "8", "--frame", "0",
                     "--motion-seconds", "0.1"])
    assert enrolled.returncode == 0, enrolled.stderr.decode()
    assert "no motion basis" in enrolled.stderr.decode()
    assert Face.load(face).model.motion is None
    sent = _run(["facedeform.sender.cli", str(CLIP), "--face", str(face), "--params", "personal", "-o", "/dev/null"])
    err = sent.stderr.decode()
    assert sent.returncode != 0 and err.startswith("fd-send: ") and err.count("\n") == 1, err
    assert "motion basis" in err


def test_motion_basis_shape_is_checked():
    with pytest.raises(InputError):
        MotionBasis(np.arange(3), np.zeros((2, 4, 3)))
