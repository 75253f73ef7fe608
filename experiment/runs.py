"""One run: a clip through one codec at one setting, measured. Each returns a flat row for CSV/JSON.

Our codec runs through its command-line tools, exactly as a user runs it, so a
row's bytes are the bytes of the stream file the sender wrote; a baseline's
are those of its elementary stream file. Both files stay in the work folder.
"""

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from facedeform.common.errors import FdError
from facedeform.common.parameters import MAX_COMPONENTS
from facedeform.experiment import metrics
from facedeform.experiment.baselines import CODECS, encode_decode
from facedeform.experiment.clips import Clip, read_y4m, track
from facedeform.protocol.framing import packet_size

SEQUENCE = 250  # frames the one-off bytes are spread over (the JVET conditions' sequence length)


def measure(clip: Clip, decoded: list) -> dict:
    """Pixel measures of the whole decoded picture and keypoint measures of ``decoded`` frames
    against the clip (see experiment.metrics)."""
    ref, dec = clip.landmarks, track(decoded)
    dec_aligned = metrics.aligned(dec, ref)  # NaN where either has no face, as the tracks are
    psnr = metrics.psnr_rgb(clip.frames, decoded)
    return {
        "psnr": float(psnr.mean()),
        "psnr_p5": float(np.percentile(psnr, 5)),
        "ssim": metrics.ssim(clip.frames, decoded),
        "ms_ssim": metrics.ms_ssim(clip.frames, decoded),
        "vmaf": metrics.vmaf(clip.frames, decoded, clip.fps),
        "faces_found": float((~np.isnan(dec).any(axis=(1, 2))).mean()),
        "akd": metrics.akd(ref, dec),
        "mouth_akd": metrics.akd(ref, dec, metrics.MOUTH),
        "akd_aligned": metrics.akd(ref, dec_aligned),
        "mouth_akd_aligned": metrics.akd(ref, dec_aligned, metrics.MOUTH),
        "opening_corr": metrics.opening_correlation(ref, dec),
        "opening_swing": metrics.opening_swing(ref, dec),
        "eye_corr": metrics.eye_correlation(ref, dec),
        "motion_fidelity": metrics.motion_fidelity(ref, dec, clip.fps),
    }


def enroll(clip: Clip, work: Path) -> Path:
    """The speaker's own face model (with its reference picture), made by fd-enroll from the crop once
    per clip and size: the face from the first second, the motion basis from the first half of the
    clip only, with as many patterns as it has frames for."""
    path = Path(work) / f"{clip.name}_{clip.frames[0].shape[0]}.fdface"
    if not path.exists():
        half = len(clip.frames) // 2
        _tool("facedeform.sender.enroll", str(clip.path), "-o", str(path), "-q", "--seconds", "1",
              "--motion", str(MAX_COMPONENTS), "--motion-seconds", f"{half / clip.fps:.3f}")
    return path


def ours_name(layout: str, own_face: bool, every: int = 1) -> str:
    """The codec column of our runs: ours-<layout>[-own][-every<N>]."""
    return f"ours-{layout}" + ("-own" if own_face else "") + (f"-every{every}" if every > 1 else "")


def run_ours(clip: Clip, setting: str, layout: str, work: Path, own_face: bool = False,
             every: int = 1) -> tuple[dict, list]:
    """fd-send then fd-recv on the clip's crop, with the generic face or the speaker's own model
    (shared beforehand: its bytes count as one-off, with the stream header), sending one frame in
    ``every`` with parameter set ``layout`` (auto: fd-send's own choice) at ``setting``: a quantiser
    level "l3" or a rate "4k" (kbit/s); returns the row and the decoded frames, at the crop's size."""
    size = clip.frames[0].shape[0]
    name = ours_name(layout, own_face, every)
    stream = Path(work) / f"{clip.name}_{size}_{name}_{setting}.fd"
    face = ["--face", str(enroll(clip, work))] if own_face else []
    rate = ["--level", setting[1:]] if setting.startswith("l") else ["--bitrate", setting[:-1]]
    started = time.perf_counter()
    sent = _tool("facedeform.sender.cli", str(clip.path), *rate, "--params", layout, "--send-every", str(every),
                 "-o", str(stream), "--json", *(face + ["--face-by-id"] if own_face else []))
    encode_s = time.perf_counter() - started
    started = time.perf_counter()
    decoded = receive(stream, size, face[1:])
    decode_s = time.perf_counter() - started
    data = stream.read_bytes()
    header_size = packet_size(data, 1)
    if header_size is None:
        raise FdError(f"{stream}: no whole header packet")
    header = 1 + header_size
    n = len(clip.frames)
    row = {"clip": clip.name, "size": size, "codec": name, "setting": setting,
           "look": "picture" if own_face else "shaded",
           "frames": n, "fps": clip.fps, "stream_bytes": len(data) - header,
           "oneoff_bytes": header + (Path(face[1]).stat().st_size if own_face else 0),
           "encode_fps": n / encode_s, "decode_fps": n / decode_s,
           # what the rate control keeps within 10 % of the rate asked for (fd-send's own count)
           "costliest_2s_bps": 1000 * json.loads(sent.stderr.splitlines()[-1])["costliest_2s_kbit_per_s"]}
    return {**row, **rates(row), **measure(clip, decoded)}, decoded


def receive(stream: Path, size: int, face: list) -> list:
    """fd-recv's frames of a stream file at ``size`` x ``size``: the whole picture with the speaker's
    model (``face``: [path]), the shaded generic face without one ([])."""
    look = ["--look", "picture"] if face else []
    return read_y4m(_tool("facedeform.receiver.cli", str(stream), "-o", "-", "--size", str(size), "-q",
                          *(["--face", *face] if face else []), *look).stdout)


def run_baseline(clip: Clip, codec: str, setting: int, work: Path) -> tuple[dict, list]:
    """A conventional codec at a constant-quality ``setting`` (CRF or QP); returns the row and the
    decoded frames."""
    size = clip.frames[0].shape[0]
    spec = CODECS[codec]
    stream = Path(work) / f"{clip.name}_{size}_{codec}_{spec.knob}{setting}.{spec.suffix}"
    coded = encode_decode(clip.frames, clip.fps, codec, setting, stream)
    n = len(clip.frames)
    row = {"clip": clip.name, "size": size, "codec": codec, "setting": f"{spec.knob}{setting}", "look": "picture",
           "frames": n, "fps": clip.fps, "stream_bytes": coded.coded_bytes, "oneoff_bytes": 0,
           "encode_fps": n / coded.encode_seconds, "decode_fps": n / coded.decode_seconds}
    return {**row, **rates(row), **measure(clip, coded.frames)}, coded.frames


def rates(row: dict) -> dict:
    """bits per second of the per-frame stream alone, and with the one-off bytes spread over SEQUENCE
    frames."""
    per_frame = 8 * row["stream_bytes"] * row["fps"] / row["frames"]
    return {"bitrate_bps": per_frame, "bitrate_oneoff_bps": per_frame + 8 * row["oneoff_bytes"] * row["fps"] / SEQUENCE}


def _tool(module: str, *args: str) -> subprocess.CompletedProcess:
    """Runs one of our command-line tools (its output and its stderr, as bytes); its one-line error
    becomes an FdError here."""
    done = subprocess.run([sys.executable, "-m", module, *args], capture_output=True)
    if done.returncode != 0:
        lines = done.stderr.decode(errors="replace").strip().splitlines() or [f"{module} failed"]
        raise FdError(lines[-1])
    return done
