"""Conventional codecs as baselines: code a clip at a constant-quality setting, decode it, count its bytes.

H.264 (x264), H.265 (x265), AV1 (SVT-AV1) and H.266 (VVenC) through the static
FFmpeg of the imageio-ffmpeg wheel, one source for every encoder, decoder and
libvmaf, so baselines need no system FFmpeg. Each codes the crop's RGB frames
(converted to 4:2:0 by FFmpeg, as any camera pipeline would) into an
elementary stream file without a container: the file's bytes are the coded
bytes, the same thing our codec's per-frame rate counts. Every encoder runs on
one thread, as every speed here is measured; a keyframe at most every 250
frames (the JVET conditions' sequence length). The ladder of a codec starts at
its floor, the most coarse quantiser its encoder accepts, and goes up by
quantiser steps (3; 6 for VVenC, whose rate moves less per step: about 1.3 to 2
times the rate a rung on 256x256 face crops).
"""

import os
import subprocess
import time
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from facedeform.common.errors import FdError, InputError


@dataclass(frozen=True)
class Codec:
    encoder: str  # FFmpeg encoder
    stream: str  # FFmpeg's elementary-stream format, for writing and reading it back
    suffix: str
    knob: str  # constant-quality option
    coarsest: int  # its most coarse value: the codec's floor
    step: int  # between rungs of the ladder (VVenC's rate moves less per QP step)
    options: tuple  # further encoder options


#: name -> how FFmpeg codes it (presets as fast as a live link wants, quality left to the quantiser)
CODECS = {
    "x264": Codec("libx264", "h264", "264", "crf", 51, 3, ("-preset", "medium", "-g", "250", "-threads", "1")),
    "x265": Codec("libx265", "hevc", "265", "crf", 51, 3, (
        "-preset", "medium", "-g", "250", "-x265-params", "log-level=error:pools=none:frame-threads=1")),
    "av1": Codec("libsvtav1", "obu", "obu", "crf", 63, 3, ("-preset", "8", "-g", "250", "-svtav1-params", "lp=1")),
    "vvc": Codec("libvvenc", "vvc", "266", "qp", 63, 6, ("-preset", "faster", "-period", "10", "-threads", "1")),
}


@dataclass(frozen=True)
class CodedClip:
    codec: str
    setting: int  # the constant-quality value (CRF or QP)
    path: Path  # the elementary stream
    coded_bytes: int
    frames: list  # decoded (H, W, 3) uint8 RGB frames, one per input frame
    encode_seconds: float
    decode_seconds: float

    def bitrate(self, fps: float) -> float:
        """Measured bits per second of the stream."""
        return 8.0 * self.coded_bytes * fps / len(self.frames)


def ffmpeg() -> str:
    """The imageio-ffmpeg wheel's static FFmpeg."""
    try:
        import imageio_ffmpeg
    except ImportError:
        raise FdError("baselines and VMAF need imageio-ffmpeg: pip install imageio-ffmpeg") from None
    return imageio_ffmpeg.get_ffmpeg_exe()


@cache
def _listed(kind: str) -> str:
    """FFmpeg's list of encoders, decoders or filters."""
    return subprocess.run([ffmpeg(), "-hide_banner", f"-{kind}"], capture_output=True, text=True).stdout


def has(kind: str, name: str) -> bool:
    """Whether the FFmpeg in use has this encoder, decoder or filter."""
    return any(line.split()[1:2] == [name] for line in _listed(kind).splitlines() if line.strip())


def check(codec: str) -> None:
    """A one-line error unless ``codec`` is known and its encoder is in the FFmpeg in use."""
    if codec not in CODECS:
        raise InputError(f"unknown baseline codec {codec!r} (known: {', '.join(CODECS)})")
    if not has("encoders", CODECS[codec].encoder):
        raise FdError(f"baseline {codec}: encoder {CODECS[codec].encoder} is missing from {ffmpeg()}")


def ladder(codec: str, rungs: int) -> list[int]:
    """The codec's quantiser values from its floor up: coarsest first, its ``step`` apart."""
    return [CODECS[codec].coarsest - CODECS[codec].step * i for i in range(rungs)]


def encode_decode(frames: list[np.ndarray], fps: float, codec: str, setting: int, path: Path) -> CodedClip:
    """Codes (H, W, 3) uint8 RGB ``frames`` with ``codec`` (a key of CODECS) at quantiser ``setting``
    into the stream file ``path``, decodes it; refuses a decoder that does not give back every frame."""
    check(codec)
    spec = CODECS[codec]
    height, width = frames[0].shape[:2]
    raw = ["-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{width}x{height}"]
    pix_fmt = "yuv420p10le" if codec == "vvc" else "yuv420p"  # VVenC codes 10-bit only
    started = time.perf_counter()
    _run([*raw, "-r", f"{fps:g}", "-i", "-", "-pix_fmt", pix_fmt, "-c:v", spec.encoder,
          f"-{spec.knob}", str(setting), *spec.options, "-f", spec.stream, "-y", str(path)],
         b"".join(np.ascontiguousarray(f).tobytes() for f in frames), codec)
    encode_seconds = time.perf_counter() - started
    started = time.perf_counter()
    decoded = decode(codec, path, (width, height))
    decode_seconds = time.perf_counter() - started
    if len(decoded) != len(frames):
        raise FdError(f"baseline {codec}: its decoder gave {len(decoded)} frames for {len(frames)}; refused")
    return CodedClip(codec, setting, Path(path), Path(path).stat().st_size, decoded, encode_seconds, decode_seconds)


def decode(codec: str, path: Path, size: tuple[int, int]) -> list:
    """A baseline's stream file decoded again, (H, W, 3) uint8 RGB frames of ``size`` (width, height)."""
    data = _run(["-threads", "1", "-f", CODECS[codec].stream, "-i", str(path), "-f", "rawvideo", "-pix_fmt", "rgb24",
                 "-fps_mode", "passthrough", "-"], b"", codec)
    return list(np.frombuffer(data, np.uint8).reshape(-1, size[1], size[0], 3))


def _run(args: list, data: bytes, what: str) -> bytes:
    """FFmpeg with ``data`` on stdin; its last line of error becomes a one-line FdError."""
    env = {**os.environ, "SVT_LOG": "1"}  # SVT-AV1 prints its configuration banner unless told not to
    done = subprocess.run([ffmpeg(), "-hide_banner", "-loglevel", "error", "-y", *args], input=data,
                          capture_output=True, env=env)
    if done.returncode != 0:
        lines = done.stderr.decode(errors="replace").strip().splitlines() or ["(no message)"]
        raise FdError(f"{what}: ffmpeg failed: {lines[-1]}")
    return done.stdout
