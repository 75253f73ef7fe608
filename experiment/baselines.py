"""Conventional codecs as baselines: encode a clip at a target bitrate, decode it, count its bytes.

H.264 (x264), H.265 (x265) and AV1 (SVT-AV1) through PyAV, whose wheels carry
the encoders, so baselines need no system FFmpeg. The byte count is that of the
coded video packets (the elementary stream), the same thing our codec's
bitrate counts; container overhead is left out for both.
"""

import os
import time
from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from common.errors import InputError

os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 prints its configuration banner unless told not to

#: name -> (PyAV encoder, options): settings for a live link (no look-ahead beyond what rate control needs)
CODECS = {
    "x264": ("libx264", {"preset": "medium", "threads": "1"}),
    "x265": ("libx265", {"preset": "medium", "x265-params": "log-level=error:pools=none:frame-threads=1"}),
    "av1": ("libsvtav1", {"preset": "8", "svtav1-params": "lp=1"}),
}


@dataclass(frozen=True)
class CodedClip:
    codec: str
    target_bps: int
    coded_bytes: int  # sum of the coded packets' sizes
    frames: list  # decoded (H, W, 3) uint8 RGB frames, one per input frame
    encode_seconds: float
    decode_seconds: float

    def bitrate(self, fps: float) -> float:
        """Measured bits per second of the coded packets."""
        return 8.0 * self.coded_bytes * fps / len(self.frames)


def encode_decode(frames: list[np.ndarray], fps: float, codec: str, target_bps: int) -> CodedClip:
    """Codes (H, W, 3) uint8 RGB ``frames`` with ``codec`` (a key of CODECS) at ``target_bps``, decodes them."""
    import av

    if codec not in CODECS:
        raise InputError(f"unknown baseline codec {codec!r} (known: {', '.join(CODECS)})")
    encoder, options = CODECS[codec]
    height, width = frames[0].shape[:2]
    context = av.CodecContext.create(encoder, "w")
    context.width, context.height, context.pix_fmt = width, height, "yuv420p"
    context.time_base = 1 / Fraction(fps).limit_denominator(1001)
    context.framerate = Fraction(fps).limit_denominator(1001)
    context.bit_rate = int(target_bps)
    context.options = dict(options)
    context.thread_count = 1  # one core, as every speed here is measured; and x264 threads are not bit-exact
    started = time.perf_counter()
    packets = []
    for i, rgb in enumerate(frames):
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
        frame.pts = i
        packets += context.encode(frame)
    packets += context.encode(None)
    encode_seconds = time.perf_counter() - started
    coded = sum(p.size for p in packets)

    decoder = av.CodecContext.create(decoder_for(codec), "r")
    if context.extradata:
        decoder.extradata = context.extradata
    started = time.perf_counter()
    decoded = [f.to_ndarray(format="rgb24") for p in packets for f in decoder.decode(p)]
    decoded += [f.to_ndarray(format="rgb24") for f in decoder.decode(None)]
    decode_seconds = time.perf_counter() - started
    if len(decoded) != len(frames):
        raise InputError(f"{codec} returned {len(decoded)} frames for {len(frames)}")
    return CodedClip(codec, int(target_bps), coded, decoded, encode_seconds, decode_seconds)


def decoder_for(codec: str) -> str:
    """The decoder for a baseline's bitstream."""
    return {"x264": "h264", "x265": "hevc", "av1": "libdav1d"}[codec]
