"""Test clips as every codec sees them: a square face crop at a fixed size, stored losslessly.

As in the JVET tests of generative face video coding, each clip is cut to a
square around the face (the same crop for the whole clip, from the face's
extent over all frames) and scaled to 256x256 or 512x512. The crop is written
as lossless H.264 so that our sender, which reads files, and the baselines,
which take frames, start from the same pixels.
"""

from dataclasses import dataclass
from itertools import islice
from pathlib import Path

import cv2
import numpy as np

from common.errors import NoFaceError
from sender.sources import VideoSource

MARGIN = 1.8  # crop side over the face's largest extent: forehead to chin with room around


@dataclass(frozen=True)
class Clip:
    name: str
    path: Path  # the lossless crop
    fps: float
    frames: list  # (size, size, 3) uint8 RGB
    landmarks: np.ndarray  # (t, 468, 3) float32 tracked on the crop, NaN without a face


def track(frames_rgb: list) -> np.ndarray:
    """(t, 468, 3) float32 landmarks of RGB frames (NaN rows where no face is found)."""
    from sender.tracker import FaceTracker

    tracker = FaceTracker()
    out = np.full((len(frames_rgb), 468, 3), np.nan, np.float32)
    for i, rgb in enumerate(frames_rgb):
        found = tracker.track(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        if found is not None:
            out[i] = found
    return out


def prepare(source: Path, size: int, out_dir: Path, seconds: float | None = None) -> Clip:
    """Reads ``source``, crops the face, scales to ``size``, writes ``out_dir/<name>_<size>.mp4``."""
    video = VideoSource(source)
    limit = None if seconds is None else max(1, round(seconds * video.fps))
    rgb = [cv2.cvtColor(f, cv2.COLOR_BGR2RGB) for f in islice(video.frames(), limit)]
    found = track(rgb)
    seen = ~np.isnan(found).any(axis=(1, 2))
    if not seen.any():
        raise NoFaceError(f"{source}: no face found in any frame")
    lo = np.nanmin(found[seen, :, :2], axis=(0, 1))
    hi = np.nanmax(found[seen, :, :2], axis=(0, 1))
    centre, side = (lo + hi) / 2, MARGIN * float(np.max(hi - lo))
    scale = size / side
    affine = np.array([[scale, 0, size / 2 - scale * centre[0]], [0, scale, size / 2 - scale * centre[1]]])
    crops = [cv2.warpAffine(f, affine, (size, size), flags=cv2.INTER_AREA, borderMode=cv2.BORDER_REPLICATE)
             for f in rgb]
    name = Path(source).stem
    path = Path(out_dir) / f"{name}_{size}.mp4"
    write_lossless(path, crops, video.fps)
    return load(name, path, video.fps)


def load(name: str, path: Path, fps: float) -> Clip:
    """A prepared crop read back (what a worker process does instead of receiving the frames)."""
    import av

    with av.open(str(path)) as container:
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    return Clip(name, Path(path), fps, frames, track(frames))


def write_lossless(path: Path, frames: list, fps: float) -> None:
    """(H, W, 3) uint8 RGB frames as lossless H.264 (4:2:0, QP 0) that OpenCV and PyAV read."""
    from fractions import Fraction

    import av

    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
        stream.width, stream.height = frames[0].shape[1], frames[0].shape[0]
        stream.pix_fmt, stream.options = "yuv420p", {"qp": "0", "preset": "veryfast"}
        for rgb in frames:
            container.mux(stream.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24")))
        container.mux(stream.encode(None))


def read_y4m(data: bytes) -> list:
    """(H, W, 3) uint8 RGB frames of a 4:2:0 Y4M byte string (what fd-recv writes)."""
    header, _, rest = data.partition(b"\n")
    fields = {f[:1]: f[1:] for f in header.split(b" ")[1:]}
    w, h = int(fields[b"W"]), int(fields[b"H"])
    size = w * h * 3 // 2
    frames = []
    while rest.startswith(b"FRAME"):
        start = rest.index(b"\n") + 1
        yuv = np.frombuffer(rest[start:start + size], np.uint8).reshape(h * 3 // 2, w)
        frames.append(cv2.cvtColor(yuv, cv2.COLOR_YUV2RGB_I420))
        rest = rest[start + size:]
    return frames
