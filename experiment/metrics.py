"""How close a decoded talking-face video is to its original.

Pixel measures take the whole decoded picture against the face crop every
codec was given, as generative face video coding papers and the JVET tests
do: PSNR as the mean of the R, G and B PSNRs, per frame; SSIM and MS-SSIM on
luma (BT.601 Y); VMAF with libvmaf's default model through FFmpeg. Keypoint
measures run our tracker on both videos: the average keypoint distance (AKD)
of talking-head codec papers, over the inter-ocular distance so that it does
not depend on resolution, for the whole face and for the mouth alone (also
after a per-frame similarity alignment, which leaves shape and motion), the
correlation of the mouth opening over time, and the motion fidelity of the
mouth and jaw (sender/fidelity.py's measure, taken on the decoded video: how
far each video's pose-free motion about its own rest frame is from the
original's, over the original's motion). The masked PSNR and SSIM serve
benchmarks/bench_visibility.py, which measures inside the face.
"""

from pathlib import Path

import cv2
import numpy as np

from facedeform.codec.model.face_model import load_base_face
from facedeform.codec.model.head_pose import image_to_face_axes
from facedeform.sender.calibrate import eye_opening, inter_ocular, lip_gap
from facedeform.sender.fidelity import MOUTH_JAW_LANDMARKS
from facedeform.sender.pose import STABLE_LANDMARKS, fit_pose

#: Lip landmarks of the tracker (outer and inner contours).
MOUTH = (0, 13, 14, 17, 37, 39, 40, 61, 78, 80, 81, 82, 84, 87, 88, 91, 95, 146, 178, 181, 185, 191,
         267, 269, 270, 291, 308, 310, 311, 312, 314, 317, 318, 321, 324, 375, 402, 405, 409, 415)


def akd(reference: np.ndarray, decoded: np.ndarray, indices=None) -> float:
    """Mean image-plane distance between (t, 468, 2+) keypoint tracks over the reference's inter-ocular
    distance, on frames where both have a face (NaN rows mark frames without one)."""
    ref, dec = np.asarray(reference)[..., :2], np.asarray(decoded)[..., :2]
    both = ~(np.isnan(ref).any(axis=(1, 2)) | np.isnan(dec).any(axis=(1, 2)))
    if not both.any():
        return float("nan")
    pick = slice(None) if indices is None else list(indices)
    dist = np.linalg.norm(ref[both][:, pick] - dec[both][:, pick], axis=2).mean(axis=1)
    return float((dist / inter_ocular(ref[both])).mean())


def similarities(decoded: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(t, 2, 3) per-frame 2-D similarity (an affine matrix) that best fits the decoded keypoints
    (t, 468, 2+) onto the reference's; identity on frames where either has no face (NaN rows)."""
    dec = np.asarray(decoded, dtype=np.float64)[..., :2]
    ref = np.asarray(reference, dtype=np.float64)[..., :2]
    out = np.tile(np.eye(2, 3), (len(dec), 1, 1))
    both = ~(np.isnan(dec).any(axis=(1, 2)) | np.isnan(ref).any(axis=(1, 2)))
    z_dec = dec[both, :, 0] + 1j * dec[both, :, 1]
    z_ref = ref[both, :, 0] + 1j * ref[both, :, 1]
    mu_dec, mu_ref = z_dec.mean(axis=1), z_ref.mean(axis=1)
    a = ((z_ref - mu_ref[:, None]) * np.conj(z_dec - mu_dec[:, None])).sum(axis=1)
    a = a / (np.abs(z_dec - mu_dec[:, None]) ** 2).sum(axis=1)
    shift = mu_ref - a * mu_dec
    out[both] = np.stack([np.stack([a.real, -a.imag, shift.real], -1), np.stack([a.imag, a.real, shift.imag], -1)], 1)
    return out


def aligned(decoded: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(t, 468, 2) decoded keypoints moved by the per-frame 2-D similarity that best fits them to the
    reference's: what is left is shape and motion, not where or how large the face is drawn."""
    dec = np.asarray(decoded, dtype=np.float64)[..., :2]
    m = similarities(decoded, reference)
    return np.einsum("tij,tnj->tni", m[:, :, :2], dec) + m[:, None, :, 2]


def _correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of two series over the frames where both are known (NaN if either is flat)."""
    both = ~(np.isnan(a) | np.isnan(b))
    if both.sum() < 3 or np.ptp(a[both]) == 0 or np.ptp(b[both]) == 0:
        return float("nan")
    return float(np.corrcoef(a[both], b[both])[0, 1])


def opening_correlation(reference: np.ndarray, decoded: np.ndarray) -> float:
    """Pearson correlation of the mouth opening of two keypoint tracks (frames with a face in both)."""
    return _correlation(lip_gap(np.asarray(reference)[..., :2]), lip_gap(np.asarray(decoded)[..., :2]))


def eye_correlation(reference: np.ndarray, decoded: np.ndarray) -> float:
    """Pearson correlation of the eye opening (both eyes' mean) of two keypoint tracks."""
    return _correlation(eye_opening(np.asarray(reference)[..., :2]), eye_opening(np.asarray(decoded)[..., :2]))


#: Percentiles whose distance is a series' swing: its range without the odd tracking glitch.
SWING = (5.0, 95.0)


def opening_swing(reference: np.ndarray, decoded: np.ndarray) -> float:
    """How far the decoded mouth opens and closes over how far the original's does: the ratio of
    their mouth openings' swings (5th to 95th percentile, frames with a face in both); 1 is the
    speaker's own amplitude, below 1 a muted mouth."""
    return _swing_ratio(lip_gap(np.asarray(reference)[..., :2]), lip_gap(np.asarray(decoded)[..., :2]))


def eye_swing(reference: np.ndarray, decoded: np.ndarray) -> float:
    """As :func:`opening_swing`, of the eyes' opening (both eyes' mean): below 1, blinks drawn
    shallower than the speaker's (which the correlation, blind to scale, does not show)."""
    return _swing_ratio(eye_opening(np.asarray(reference)[..., :2]), eye_opening(np.asarray(decoded)[..., :2]))


def _swing_ratio(a: np.ndarray, b: np.ndarray) -> float:
    both = ~(np.isnan(a) | np.isnan(b))
    if both.sum() < 3:
        return float("nan")
    spread = swing(a[both])
    return swing(b[both]) / spread if spread > 0 else float("nan")


def swing(series: np.ndarray) -> float:
    """The 5th to 95th percentile range (SWING) of a series' known (not NaN) values."""
    values = np.asarray(series, dtype=np.float64)
    return float(np.subtract(*np.percentile(values[~np.isnan(values)], SWING[::-1])))


def blinks(landmarks: np.ndarray) -> bool:
    """Whether a (t, 468, 2+) track shows a blink: an eye opening below half its median."""
    e = eye_opening(np.asarray(landmarks)[..., :2])
    e = e[~np.isnan(e)]
    return bool(len(e) and e.min() < 0.5 * np.median(e))


def pose_free(landmarks: np.ndarray) -> np.ndarray:
    """(t, 468, 3) tracker landmarks (pixels; NaN rows without a face) -> the same in base-face units
    with the head pose removed, as the sender sees them."""
    stable = list(STABLE_LANDMARKS)
    reference = load_base_face().vertices[stable]
    out = np.full(np.shape(landmarks), np.nan)
    for i, lm in enumerate(np.asarray(landmarks, dtype=np.float64)):
        if not np.isnan(lm).any():
            points = image_to_face_axes(lm)
            out[i] = fit_pose(points[stable], reference).apply(points)
    return out


def motion_fidelity(reference: np.ndarray, decoded: np.ndarray, fps: float) -> float:
    """Relative error of the decoded mouth-and-jaw motion: rms over the 41 landmarks of
    sender.fidelity and the frames with a face in both of (decoded - its rest) - (reference - its
    rest), over the rms of (reference - its rest); 0 perfect, 1 a frozen face. The rest frame is the
    reference's frame of the first second with the mouth most closed (as the sender picks it), both
    tracks (t, 468, 3) in pixels."""
    ref, dec = pose_free(reference), pose_free(decoded)
    both = ~(np.isnan(ref).any(axis=(1, 2)) | np.isnan(dec).any(axis=(1, 2)))
    first = np.flatnonzero(both[:max(1, round(fps))])
    if len(first) == 0 or both.sum() < 2:
        return float("nan")
    rest = first[np.argmin(lip_gap(np.asarray(reference)[first]))]
    idx = list(MOUTH_JAW_LANDMARKS)
    ref_motion = ref[both][:, idx] - ref[rest, idx]
    dec_motion = dec[both][:, idx] - dec[rest, idx]
    rms = lambda d: float(np.sqrt(np.mean(np.sum(d * d, axis=-1))))  # noqa: E731
    frozen = rms(ref_motion)
    return rms(dec_motion - ref_motion) / frozen if frozen > 0 else float("nan")


def psnr(reference: list, decoded: list, masks: list) -> float:
    """PSNR in dB over the masked pixels of all frames: (H, W, 3) uint8 frames, (H, W) bool masks."""
    err = sum(float(((r[m].astype(np.float64) - d[m]) ** 2).sum()) for r, d, m in zip(reference, decoded, masks))
    count = sum(int(m.sum()) * 3 for m in masks)
    if count == 0:
        return float("nan")
    return float("inf") if err == 0 else float(10 * np.log10(255.0 ** 2 * count / err))


def ssim(reference: list, decoded: list, masks: list | None = None) -> float:
    """Mean SSIM on luma (BT.601 Y; 11x11 Gaussian window, sigma 1.5) over the masked pixels of all
    frames, or over every pixel without ``masks``."""
    total, count = 0.0, 0
    for i, (r, d) in enumerate(zip(reference, decoded)):
        smap, _ = _ssim_maps(_luma(r), _luma(d))
        m = np.ones(smap.shape, bool) if masks is None else masks[i]
        total += float(smap[m].sum())
        count += int(m.sum())
    return total / count if count else float("nan")


#: Wang, Simoncelli and Bovik's (2003) weights of MS-SSIM's five scales, finest first.
MS_SSIM_WEIGHTS = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333)


def ms_ssim(reference: list, decoded: list) -> float:
    """Mean over frames of multi-scale SSIM on luma: the contrast-structure term at the four finer
    scales and the whole SSIM at the coarsest, each scale half the size of the one before (2x2
    means), weighted as Wang et al. (negative terms count as 0)."""
    scores = []
    for r, d in zip(reference, decoded):
        x, y, score = _luma(r), _luma(d), 1.0
        for level, weight in enumerate(MS_SSIM_WEIGHTS):
            smap, cs = _ssim_maps(x, y)
            last = level == len(MS_SSIM_WEIGHTS) - 1
            score *= max(float((smap if last else cs).mean()), 0.0) ** weight
            if not last:
                half = (x.shape[1] // 2, x.shape[0] // 2)
                x = cv2.resize(x[:2 * half[1], :2 * half[0]], half, interpolation=cv2.INTER_AREA)
                y = cv2.resize(y[:2 * half[1], :2 * half[0]], half, interpolation=cv2.INTER_AREA)
        scores.append(score)
    return float(np.mean(scores))


def _luma(rgb: np.ndarray) -> np.ndarray:
    """BT.601 luma (0.299 R + 0.587 G + 0.114 B, full range) as float64."""
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float64)


def _ssim_maps(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """SSIM map and its contrast-structure part of two grey float images (8-bit range)."""
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2
    blur = lambda img: cv2.GaussianBlur(img, (11, 11), 1.5)  # noqa: E731
    mx, my = blur(x), blur(y)
    vx, vy, cxy = blur(x * x) - mx * mx, blur(y * y) - my * my, blur(x * y) - mx * my
    cs = (2 * cxy + c2) / (vx + vy + c2)
    return (2 * mx * my + c1) / (mx * mx + my * my + c1) * cs, cs


PSNR_CAP = 100.0  # dB for a channel with no error, so that identical frames give a number


def psnr_rgb(reference: list, decoded: list) -> np.ndarray:
    """Per-frame PSNR in dB of (H, W, 3) uint8 frames: the mean of the R, G and B PSNRs, each at most
    PSNR_CAP."""
    out = []
    for r, d in zip(reference, decoded):
        mse = ((r.astype(np.float64) - d) ** 2).mean(axis=(0, 1))
        out.append(np.mean(np.minimum(10 * np.log10(255.0 ** 2 / np.maximum(mse, 1e-300)), PSNR_CAP)))
    return np.array(out)


def vmaf_available() -> None:
    """A one-line error unless the FFmpeg in use has the libvmaf filter."""
    from facedeform.common.errors import FdError
    from facedeform.experiment.baselines import ffmpeg, has

    if not has("filters", "libvmaf"):
        raise FdError(f"VMAF: filter libvmaf is missing from {ffmpeg()}")


def vmaf(reference: list, decoded: list, fps: float) -> float:
    """Mean VMAF (libvmaf's default model, through FFmpeg's libvmaf filter) of (H, W, 3) uint8 RGB
    frames, both converted to 4:2:0 as FFmpeg does by default."""
    import json
    import subprocess
    import tempfile

    from facedeform.common.errors import FdError
    from facedeform.experiment.baselines import ffmpeg

    vmaf_available()
    height, width = reference[0].shape[:2]
    raw = ["-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{width}x{height}", "-r", f"{fps:g}", "-i"]
    with tempfile.TemporaryDirectory(prefix="fd-vmaf-") as tmp:
        paths = [Path(tmp) / "decoded.rgb", Path(tmp) / "reference.rgb", Path(tmp) / "vmaf.json"]
        for path, frames in zip(paths, (decoded, reference)):
            with open(path, "wb") as f:
                for frame in frames:
                    f.write(np.ascontiguousarray(frame).tobytes())
        done = subprocess.run([ffmpeg(), "-hide_banner", "-loglevel", "error", *raw, str(paths[0]), *raw,
                               str(paths[1]), "-lavfi", "[0:v]format=yuv420p[d];[1:v]format=yuv420p[r];"
                               f"[d][r]libvmaf=log_fmt=json:log_path={paths[2]}:n_threads=1", "-f", "null", "-"],
                              capture_output=True, stdin=subprocess.DEVNULL)
        if done.returncode != 0:
            lines = done.stderr.decode(errors="replace").strip().splitlines() or ["(no message)"]
            raise FdError(f"VMAF: ffmpeg failed: {lines[-1]}")
        return float(json.loads(paths[2].read_text())["pooled_metrics"]["vmaf"]["mean"])
