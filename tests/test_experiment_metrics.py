"""Quality measures: zero error scores perfectly, known errors score as computed by hand."""

import numpy as np
import pytest

from facedeform.experiment.metrics import (
    MOUTH,
    akd,
    blinks,
    eye_correlation,
    eye_swing,
    ms_ssim,
    opening_correlation,
    opening_swing,
    psnr,
    psnr_rgb,
    ssim,
    vmaf,
)
from facedeform.sender.calibrate import eye_opening, lip_gap


def track(t=10, seed=0):
    rng = np.random.default_rng(seed)
    base = rng.uniform(100, 300, size=(468, 2))
    base[[33, 133]] = [[150, 150], [170, 150]]
    base[[362, 263]] = [[230, 150], [250, 150]]  # eye centres 80 px apart
    lm = np.repeat(base[None], t, axis=0)
    lm[:, 14, 1] += np.linspace(0, 20, t)  # the mouth opens
    return lm


def test_akd_is_zero_for_identical_tracks_and_scales_with_the_inter_ocular_distance():
    ref = track()
    assert akd(ref, ref) == 0.0
    np.testing.assert_allclose(akd(ref, ref + [8.0, 0.0]), 8.0 / 80.0)
    np.testing.assert_allclose(akd(ref * 2, ref * 2 + [8.0, 0.0]), 8.0 / 160.0)


def test_mouth_akd_sees_only_the_mouth():
    ref = track()
    moved = ref.copy()
    moved[:, 10] += 50.0  # a forehead point
    assert akd(ref, moved, MOUTH) == 0.0
    assert akd(ref, moved) > 0.0


def test_frames_without_a_face_are_left_out():
    ref, dec = track(), track()
    dec[3] = np.nan
    dec[4] += 1000.0
    assert akd(ref[:3], dec[:3]) == 0.0
    assert akd(ref, dec) == pytest.approx(akd(ref[4:5], dec[4:5]) / 9)


def test_mouth_opening_correlation():
    ref = track()
    np.testing.assert_allclose(lip_gap(ref)[-1], np.linalg.norm(ref[-1, 13] - ref[-1, 14]) / 80.0)
    assert opening_correlation(ref, ref) == pytest.approx(1.0)
    frozen = np.repeat(ref[:1], len(ref), axis=0)
    assert np.isnan(opening_correlation(ref, frozen))


def test_a_mouth_that_opens_half_as_far_swings_half_as_far():
    ref = track(t=40)
    ref[:, 13] = [200.0, 240.0]  # the upper lip, the lower one opening below it from 2 px to 22 px
    ref[:, 14] = np.column_stack([np.full(40, 200.0), np.linspace(242.0, 262.0, 40)])
    muted = ref.copy()
    muted[:, 14, 1] = ref[0, 14, 1] + 0.5 * (ref[:, 14, 1] - ref[0, 14, 1])
    assert lip_gap(ref)[-1] > lip_gap(ref)[0]
    assert opening_swing(ref, ref) == pytest.approx(1.0)
    assert opening_swing(ref, muted) == pytest.approx(0.5, abs=0.02)
    assert opening_correlation(ref, muted) == pytest.approx(1.0)


def test_a_blink_is_seen_and_an_open_stare_does_not_follow_it():
    ref = track(t=30)
    ref[:, [159, 145]] = [[160.0, 144.0], [160.0, 150.0]]  # lids 6 px apart, eyes 20 px wide
    ref[:, [386, 374]] = [[240.0, 144.0], [240.0, 150.0]]
    stare = ref.copy()
    ref[12:15, [159, 386], 1] = 149.0  # a blink of three frames
    np.testing.assert_allclose(eye_opening(stare)[0], 6.0 / 20.0)
    assert blinks(ref) and not blinks(stare)
    assert eye_correlation(ref, ref) == pytest.approx(1.0)
    assert np.isnan(eye_correlation(ref, stare))  # a face that never blinks follows no blink


def test_a_blink_half_as_deep_swings_half_as_far():
    ref = track(t=40)
    ref[:, [159, 145]] = [[160.0, 144.0], [160.0, 150.0]]
    ref[:, [386, 374]] = [[240.0, 144.0], [240.0, 150.0]]
    shallow = ref.copy()
    ref[:, [159, 386], 1] = np.linspace(144.0, 150.0, 40)[:, None]  # the lids close over the clip
    shallow[:, [159, 386], 1] = np.linspace(144.0, 147.0, 40)[:, None]  # half as far
    assert eye_swing(ref, ref) == pytest.approx(1.0)
    assert eye_swing(ref, shallow) == pytest.approx(0.5, abs=0.02)
    assert eye_correlation(ref, shallow) == pytest.approx(1.0)


def test_psnr_and_ssim_inside_the_mask():
    rng = np.random.default_rng(1)
    a = rng.integers(0, 256, (64, 64, 3), dtype=np.uint8)
    b = a.copy()
    mask = np.zeros((64, 64), bool)
    mask[16:48, 16:48] = True
    b[~mask] = 0  # outside the face: not counted
    assert psnr([a], [b], [mask]) == float("inf")
    assert ssim([a], [a], [mask]) == pytest.approx(1.0)
    c = a.astype(int)
    c[mask] += 10
    c = np.clip(c, 0, 255).astype(np.uint8)
    mse = ((a[mask].astype(float) - c[mask]) ** 2).mean()
    assert psnr([a], [c], [mask]) == pytest.approx(10 * np.log10(255 ** 2 / mse))
    assert ssim([a], [c], [mask]) < 1.0


def test_alignment_removes_a_similarity_but_not_a_change_of_shape():
    from facedeform.experiment.metrics import aligned

    ref = track()
    angle, scale, shift = 0.3, 1.7, np.array([40.0, -25.0])
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    moved = ref @ rot.T * scale + shift
    np.testing.assert_allclose(aligned(moved, ref), ref, atol=1e-9)
    bent = moved.copy()
    bent[:, 14] += 30.0
    assert akd(ref, aligned(bent, ref), MOUTH) > 0.005  # 30 px / 1.7 on one of 40 points, over 80 px


def face_track(t=12, scale=200.0, opening=0.03):
    """(t, 468, 3) pixel landmarks of the base face whose jaw line and lower lip drop over time."""
    from facedeform.codec.model.face_model import load_base_face
    from facedeform.sender.fidelity import MOUTH_JAW_LANDMARKS

    v = load_base_face().vertices
    frames = np.repeat(v[None], t, axis=0)
    moving = [i for i in MOUTH_JAW_LANDMARKS if v[i, 1] < v[14, 1] + 1e-9]
    frames[:, moving, 1] -= np.linspace(0, opening, t)[:, None]
    return frames * [scale, -scale, -scale] + [320, 240, 0]


def test_motion_fidelity_is_zero_for_the_same_motion_whatever_the_pose_and_one_for_a_frozen_face():
    from scipy.spatial.transform import Rotation

    from facedeform.experiment.metrics import motion_fidelity

    ref = face_track()
    assert motion_fidelity(ref, ref, 25) == pytest.approx(0, abs=1e-9)
    moved = ref.copy()
    for i in range(len(moved)):  # the decoded face drawn turned, smaller and elsewhere: same motion
        rot = Rotation.from_euler("xyz", [0, 5 + i, 3], degrees=True).as_matrix()
        moved[i] = (moved[i] - 300) @ rot.T * 0.7 + [100, 50, 0]
    assert motion_fidelity(ref, moved, 25) < 0.05
    frozen = np.repeat(ref[:1], len(ref), axis=0)
    assert motion_fidelity(ref, frozen, 25) == pytest.approx(1, abs=1e-6)
    half = face_track(opening=0.015)
    assert motion_fidelity(ref, half, 25) == pytest.approx(0.5, abs=0.05)


def noisy_pair(seed=2, size=96, t=3):
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size]
    frames = [np.stack([(128 + 90 * np.sin((x + k) / 7.0)), (128 + 90 * np.cos(y / 9.0)), 60 + 0 * x], -1)
              .astype(np.uint8) for k in range(t)]
    noisy = [np.clip(f + rng.normal(0, 12, f.shape), 0, 255).astype(np.uint8) for f in frames]
    return frames, noisy


def test_psnr_is_the_mean_of_the_three_channels_per_frame():
    a = np.full((8, 8, 3), 100, np.uint8)
    b = a.copy()
    b[..., 0] += 10  # red off by 10 everywhere, green and blue exact
    c = a.copy()
    c[..., 2] -= 5
    red = 10 * np.log10(255 ** 2 / 100)
    blue = 10 * np.log10(255 ** 2 / 25)
    np.testing.assert_allclose(psnr_rgb([a, a], [b, c]), [(red + 200) / 3, (blue + 200) / 3])
    np.testing.assert_allclose(psnr_rgb([a], [a]), [100.0])  # no error: each channel at the cap


def test_ssim_and_ms_ssim_on_the_whole_picture():
    frames, noisy = noisy_pair()
    assert ssim(frames, frames) == pytest.approx(1.0)
    assert ms_ssim(frames, frames) == pytest.approx(1.0)
    s, m = ssim(frames, noisy), ms_ssim(frames, noisy)
    assert 0.2 < s < 0.95 and s < m < 1.0  # noise hurts the finest scale most
    worse = [np.clip(f.astype(int) + (n.astype(int) - f) * 2, 0, 255).astype(np.uint8) for f, n in zip(frames, noisy)]
    assert ssim(frames, worse) < s and ms_ssim(frames, worse) < m


def test_vmaf_is_near_100_for_the_same_video_and_falls_with_noise():
    frames, noisy = noisy_pair(t=4)
    same = vmaf(frames, frames, 25.0)
    assert 95.0 < same <= 100.0
    assert vmaf(frames, noisy, 25.0) < same - 5


def test_the_similarity_fits_the_decoded_keypoints_onto_the_reference():
    from facedeform.experiment.metrics import similarities

    ref = track(t=2)
    dec = ref * 0.5 + [20, 10]  # drawn at half size, elsewhere
    dec[1] = np.nan  # no face found in the second decoded frame: identity
    m = similarities(dec, ref)
    np.testing.assert_allclose(m[0], [[2, 0, -40], [0, 2, -20]], atol=1e-9)
    np.testing.assert_array_equal(m[1], np.eye(2, 3))


def test_bd_rate_is_the_rate_saved_at_equal_quality():
    from facedeform.experiment.report import bd_rate

    quality = np.array([20.0, 24.0, 28.0, 32.0])
    rate = np.array([2.0, 5.0, 12.0, 30.0])
    assert bd_rate((rate / 2, quality), (rate, quality)) == pytest.approx(-50.0)
    assert bd_rate((rate * 1.25, quality), (rate, quality)) == pytest.approx(25.0)
    # only where both curves reach: ours from 26 dB up against theirs to 24 dB is no overlap
    assert bd_rate((rate, quality + 6), (rate, quality - 8)) is None
    assert bd_rate((rate[:1], quality[:1]), (rate, quality)) is None  # one point is no curve


def test_the_bd_table_says_when_a_baseline_has_one_setting_only():
    from facedeform.experiment.report import bd_table

    def row(codec, setting, kbps, psnr):
        return {"size": 256, "codec": codec, "setting": setting, "bitrate_bps": 1000 * kbps,
                "bitrate_oneoff_bps": 1000 * kbps, "psnr": psnr, "vmaf": 3 * psnr}

    ours = [row("ours-auto-own", f"{k}k", k, 20 + k) for k in (2, 4, 8)]
    one = bd_table(ours + [row("x264", "crf51", 5, 24)])
    two = bd_table(ours + [row("x264", "crf51", 5, 24), row("x264", "crf48", 7, 26)])
    assert "one setting: run --rungs 2 or more" in one and "%" in two and "one setting" not in two
