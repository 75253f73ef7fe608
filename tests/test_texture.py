"""A texture from a frame: the warp into UV space puts every colour where the UVs say."""

import numpy as np
import pytest

from facedeform.codec.model.face_model import load_base_face
from facedeform.sender.texture import texture_from_frame, uv_to_texel

FACE = load_base_face()


def smooth_image(size, seed=0):
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size] / size
    channels = [np.sin(2 * np.pi * (a * x + b * y) + c) for a, b, c in rng.uniform(0.5, 2.0, (3, 3))]
    return np.round(127.5 + 120 * np.stack(channels, axis=2)).astype(np.uint8)


def test_a_frame_already_in_uv_layout_comes_back_unchanged():
    size = 256
    frame = smooth_image(size)
    points = uv_to_texel(FACE.uv, size)  # the face "seen" exactly where its UVs are
    texture = texture_from_frame(frame, points, FACE.uv, FACE.faces, size)
    inside = np.zeros((size, size), bool)
    t = points.mean(axis=0).astype(int)
    inside[t[1] - 40:t[1] + 40, t[0] - 40:t[0] + 40] = True
    diff = np.abs(texture.astype(int) - frame.astype(int))[inside]
    assert diff.max() <= 2


def test_a_shifted_and_scaled_face_is_undone():
    size = 256
    frame = smooth_image(512, seed=1)
    points = uv_to_texel(FACE.uv, size) * 1.5 + [40.0, 20.0]
    texture = texture_from_frame(frame, points, FACE.uv, FACE.faces, size)
    y, x = 128, 128
    sx, sy = x * 1.5 + 40.0, y * 1.5 + 20.0  # texel centre (x+0.5) maps to 1.5x+0.75+40
    expected = frame[int(round(sy + 0.25)), int(round(sx + 0.25))].astype(int)
    assert np.abs(texture[y, x].astype(int) - expected).max() <= 12


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError):
        texture_from_frame(np.zeros((10, 10), np.uint8), np.zeros((468, 2)), FACE.uv, FACE.faces)
