"""Conventional baselines: every frame comes back, the stream file is the bytes counted, more bits buy a
closer picture, and a missing encoder or a decoder that drops frames is refused in one line."""

import numpy as np
import pytest

from facedeform.common.errors import FdError, InputError
from facedeform.experiment import baselines
from facedeform.experiment.baselines import CODECS, encode_decode, ladder


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
def test_every_frame_comes_back_and_bits_buy_quality(codec, tmp_path):
    clip = moving_clip()
    floor, fine = (encode_decode(clip, 25.0, codec, setting, tmp_path / f"{setting}.{CODECS[codec].suffix}")
                   for setting in (CODECS[codec].coarsest, CODECS[codec].coarsest - 30))
    for coded in (floor, fine):
        assert len(coded.frames) == len(clip) and coded.frames[0].shape == clip[0].shape
        assert coded.coded_bytes == coded.path.stat().st_size > 0
        assert coded.bitrate(25.0) == pytest.approx(8 * coded.coded_bytes * 25.0 / len(clip))
    assert fine.coded_bytes > floor.coded_bytes
    assert mse(clip, fine.frames) < mse(clip, floor.frames)


def test_the_ladder_starts_at_the_floor():
    assert ladder("x264", 3) == [51, 48, 45]
    assert ladder("av1", 1) == [63]


def test_unknown_codec_is_one_line_error(tmp_path):
    with pytest.raises(InputError, match="unknown baseline codec 'vp8'"):
        encode_decode(moving_clip(2), 25.0, "vp8", 10, tmp_path / "x")


def test_missing_encoder_is_a_one_line_error_naming_it(monkeypatch, tmp_path):
    listed = baselines._listed("encoders")
    monkeypatch.setattr(baselines, "_listed", lambda kind: listed.replace(" libx265 ", " gone "))
    with pytest.raises(FdError, match="^baseline x265: encoder libx265 is missing from ") as error:
        encode_decode(moving_clip(2), 25.0, "x265", 51, tmp_path / "x.265")
    assert "\n" not in str(error.value)


def test_a_decoder_that_drops_frames_is_refused(monkeypatch, tmp_path):
    decode = baselines.decode
    monkeypatch.setattr(baselines, "decode", lambda *args: decode(*args)[:-1])
    with pytest.raises(FdError, match="^baseline x264: its decoder gave 3 frames for 4; refused$"):
        encode_decode(moving_clip(4), 25.0, "x264", 51, tmp_path / "x.264")
