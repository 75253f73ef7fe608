"""Conventional baselines: every frame comes back, and more bits buy a closer picture."""

import numpy as np
import pytest

from common.errors import InputError
from experiment.baselines import CODECS, encode_decode


def moving_clip(n=12, size=64):
    y, x = np.mgrid[0:size, 0:size]
    frames = []
    for t in range(n):
        img = np.zeros((size, size, 3), np.uint8)
        img[..., 0] = (128 + 100 * np.sin((x + 2 * t) / 6.0)).astype(np.uint8)
        img[..., 1] = (128 + 100 * np.cos((y - t) / 5.0)).astype(np.uint8)
        img[..., 2] = 90
        frames.append(img)
    return frames


def mse(a, b):
    return float(np.mean([(x.astype(float) - y) ** 2 for x, y in zip(a, b)]))


@pytest.mark.parametrize("codec", sorted(CODECS))
def test_every_frame_comes_back_and_bits_buy_quality(codec):
    clip = moving_clip()
    low, high = (encode_decode(clip, 25.0, codec, bps) for bps in (20_000, 400_000))
    for coded in (low, high):
        assert len(coded.frames) == len(clip) and coded.frames[0].shape == clip[0].shape
        assert coded.coded_bytes > 0
        assert coded.bitrate(25.0) == pytest.approx(8 * coded.coded_bytes * 25.0 / len(clip))
    assert high.coded_bytes > low.coded_bytes
    assert mse(clip, high.frames) < mse(clip, low.frames)


def test_unknown_codec_is_one_line_error():
    with pytest.raises(InputError, match="unknown baseline codec 'vp8'"):
        encode_decode(moving_clip(2), 25.0, "vp8", 10_000)
