"""One run: a clip through one codec at one setting, measured. Each returns a flat row for CSV/JSON.

Our codec runs through its command-line tools, exactly as a user runs it, so a
row's bytes are the bytes of the stream file the sender wrote.
"""

import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from codec.motion_basis import MAX_COMPONENTS
from common.errors import FdError
from experiment import metrics
from experiment.baselines import encode_decode
from experiment.clips import Clip, read_y4m, track
from protocol.framing import packet_size


def measure(clip: Clip, decoded: list) -> dict:
    """Keypoint and pixel measures of ``decoded`` frames against the clip (see experiment.metrics)."""
    ref, dec = clip.landmarks, track(decoded)
    dec_aligned = metrics.aligned(dec, ref)  # NaN where either has no face, as the tracks are
    warped = metrics.aligned_frames(decoded, dec, ref)
    masks = [metrics.face_mask(lm, clip.frames[0].shape[:2]) if not np.isnan(lm).any()
             else np.zeros(clip.frames[0].shape[:2], bool) for lm in ref]
    return {
        "faces_found": float((~np.isnan(dec).any(axis=(1, 2))).mean()),
        "akd": metrics.akd(ref, dec),
        "akd_aligned": metrics.akd(ref, dec_aligned),
        "mouth_akd_aligned": metrics.akd(ref, dec_aligned, metrics.MOUTH),
        "opening_corr": metrics.opening_correlation(ref, dec),
        "motion_fidelity": metrics.motion_fidelity(ref, dec, clip.fps),
        "psnr_face": metrics.psnr(clip.frames, decoded, masks),
        "ssim_face": metrics.ssim(clip.frames, decoded, masks),
        "psnr_face_aligned": metrics.psnr(clip.frames, warped, masks),
        "ssim_face_aligned": metrics.ssim(clip.frames, warped, masks),
    }


def enroll(clip: Clip, work: Path) -> Path:
    """The speaker's own face model, made by fd-enroll from the clip itself (once per clip and size);
    its motion basis learns from the first half of the clip only, with as many patterns as it has
    frames for."""
    path = Path(work) / f"{clip.name}_{clip.frames[0].shape[0]}.fdface"
    if not path.exists():
        half = len(clip.frames) // 2
        _tool("sender.enroll", str(clip.path), "-o", str(path), "-q", "--motion", str(MAX_COMPONENTS),
              "--motion-seconds", f"{half / clip.fps:.3f}")
    return path


def run_ours(clip: Clip, quality: int, layout: str, work: Path, own_face: bool = False,
             every: int = 1) -> tuple[dict, list]:
    """fd-send then fd-recv on the clip's crop, with the generic face or the speaker's own model
    (shared beforehand: its bytes count as one-off, with the stream header), sending one frame in
    ``every``; returns the row and the decoded frames."""
    size = clip.frames[0].shape[0]
    name = f"ours-{layout}" + ("-own" if own_face else "") + (f"-every{every}" if every > 1 else "")
    stream = Path(work) / f"{clip.name}_{size}_{name}_q{quality}.fd"
    face = ["--face", str(enroll(clip, work))] if own_face else []
    started = time.perf_counter()
    _tool("sender.cli", str(clip.path), "--quality", str(quality), "--params", layout, "--send-every", str(every),
          "-o", str(stream), "-q",
          *(face + ["--face-by-id"] if own_face else []))
    encode_s = time.perf_counter() - started
    started = time.perf_counter()
    decoded = read_y4m(_tool("receiver.cli", str(stream), "-o", "-", "--size", str(size), "-q", *face))
    decode_s = time.perf_counter() - started
    data = stream.read_bytes()
    header = 1 + packet_size(data, 1)
    model = Path(face[1]).stat().st_size if own_face else 0
    n = len(clip.frames)
    row = {"clip": clip.name, "size": size, "codec": name, "setting": f"q{quality}",
           "frames": n, "fps": clip.fps, "stream_bytes": len(data) - header, "oneoff_bytes": header + model,
           "bitrate_bps": 8 * (len(data) - header) * clip.fps / n,
           "encode_fps": n / encode_s, "decode_fps": n / decode_s}
    return {**row, **measure(clip, decoded)}, decoded


def run_baseline(clip: Clip, codec: str, target_bps: int) -> tuple[dict, list]:
    """A conventional codec at a target bitrate; returns the row and the decoded frames."""
    coded = encode_decode(clip.frames, clip.fps, codec, target_bps)
    n = len(clip.frames)
    row = {"clip": clip.name, "size": clip.frames[0].shape[0], "codec": codec, "setting": f"{target_bps}bps",
           "frames": n, "fps": clip.fps, "stream_bytes": coded.coded_bytes, "oneoff_bytes": 0,
           "bitrate_bps": coded.bitrate(clip.fps),
           "encode_fps": n / coded.encode_seconds, "decode_fps": n / coded.decode_seconds}
    return {**row, **measure(clip, coded.frames)}, coded.frames


def _tool(module: str, *args: str) -> bytes:
    """Runs one of our command-line tools; its one-line error becomes an FdError here."""
    done = subprocess.run([sys.executable, "-m", module, *args], capture_output=True)
    if done.returncode != 0:
        raise FdError(done.stderr.decode(errors="replace").strip().splitlines()[-1])
    return done.stdout
