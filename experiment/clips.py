"""Test clips as every codec sees them: a square face crop at a fixed size, stored losslessly.

As in the JVET tests of generative face video coding, every codec, ours
included, takes the same square face crop of each clip. The rule: the box
around every landmark the tracker finds in every frame of the clip (the union
of the per-frame landmark boxes, so a moving head stays inside); its side is
MARGIN times the larger of that box's width and height, its centre that box's
centre moved up by a tenth of the side (room for the forehead and hair, less
below the chin); the box is then shifted to lie inside the frame, and shrunk
to the frame's shorter side if it cannot fit; one box for the whole clip,
scaled to 256x256 or 512x512 with INTER_AREA. The crop is written once per
clip and size as FFV1 in RGB (bit-exact: checked on writing), at the clip's
frame rate, so that our sender and enroller, which read files, and the
baselines, which take frames, start from the same pixels.
"""

import json
import tempfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from itertools import islice
from pathlib import Path

import cv2
import numpy as np

from facedeform.common.errors import FdError, InputError, NoFaceError
from facedeform.sender.sources import VideoSource

MARGIN = 1.8  # crop side over the face's largest extent: forehead to chin with room around
RAISE = 0.1  # the crop's centre moves up by this share of its side


@dataclass(frozen=True)
class Clip:
    name: str
    path: Path  # the lossless crop
    fps: float
    frames: list  # (size, size, 3) uint8 RGB
    landmarks: np.ndarray  # (t, 468, 3) float32 tracked on the crop, NaN without a face


def track(frames_rgb: list) -> np.ndarray:
    """(t, 468, 3) float32 landmarks of RGB frames (NaN rows where no face is found)."""
    from facedeform.sender.tracker import FaceTracker

    tracker = FaceTracker()
    out = np.full((len(frames_rgb), 468, 3), np.nan, np.float32)
    for i, rgb in enumerate(frames_rgb):
        found = tracker.track(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        if found is not None:
            out[i] = found
    return out


def crop_box(landmarks: np.ndarray, width: int, height: int) -> tuple[int, int, int]:
    """(x, y, side) in pixels of the square crop of a clip whose (t, 468, 2+) landmarks (NaN rows
    without a face) are given, in a ``width`` x ``height`` frame (the rule in this module's doc)."""
    seen = ~np.isnan(landmarks).any(axis=(1, 2))
    lo = landmarks[seen, :, :2].min(axis=(0, 1))
    hi = landmarks[seen, :, :2].max(axis=(0, 1))
    side = min(MARGIN * float(np.max(hi - lo)), width, height)
    centre = (lo + hi) / 2 - [0.0, RAISE * side]
    side = int(round(side))
    x, y = (int(round(float(np.clip(c - side / 2, 0, extent - side)))) for c, extent in zip(centre, (width, height)))
    return x, y, side


def prepare(source: Path, size: int, out_dir: Path, seconds: float | None = None) -> Clip:
    """Reads ``source``, crops the face, scales to ``size``, writes ``out_dir/<name>_<size>.mkv`` and
    its crop box beside it (.json); a crop already written is read back instead (a resumed run)."""
    name = Path(source).stem
    path = Path(out_dir) / f"{name}_{size}.mkv"
    info = path.with_suffix(".json")
    if path.exists() and info.exists():
        known = json.loads(info.read_text())
        if known.get("seconds") != seconds:
            raise InputError(f"{out_dir} holds {path.name} made with --seconds {known.get('seconds')}, not "
                             f"{seconds}: use another --out")
        return load(name, path, known["fps"])
    video = VideoSource(source)
    limit = None if seconds is None else max(1, round(seconds * video.fps))
    rgb = [cv2.cvtColor(f, cv2.COLOR_BGR2RGB) for f in islice(video.frames(), limit)]
    found = track(rgb)
    if np.isnan(found).any(axis=(1, 2)).all():
        raise NoFaceError(f"{source}: no face found in any frame")
    x, y, side = crop_box(found, rgb[0].shape[1], rgb[0].shape[0])
    crops = [cv2.resize(f[y:y + side, x:x + side], (size, size), interpolation=cv2.INTER_AREA) for f in rgb]
    write_lossless(path, crops, video.fps)
    info.write_text(json.dumps({"source": str(source), "seconds": seconds, "fps": video.fps, "frames": len(crops),
                                "box": {"x": x, "y": y, "side": side}}) + "\n")
    return load(name, path, video.fps)



def crops(sources: Iterable[Path], size: int = 256) -> Iterator[tuple[Clip, Path]]:
    """(each of ``sources`` as :func:`prepare` crops it at ``size``, the folder it is in): a temporary
    folder, removed when the iteration ends, which the caller may write in too (the benchmarks)."""
    with tempfile.TemporaryDirectory(prefix="fd-bench-") as tmp:
        work = Path(tmp)
        for source in sources:
            yield prepare(Path(source), size, work), work

def load(name: str, path: Path, fps: float) -> Clip:
    """A prepared crop read back (what a worker process does instead of receiving the frames)."""
    frames = read_video(path)
    return Clip(name, Path(path), fps, frames, track(frames))


def read_video(path: Path) -> list:
    """(H, W, 3) uint8 RGB frames of a video file, through PyAV."""
    import av

    with av.open(str(path)) as container:
        return [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]


def write_lossless(path: Path, frames: list, fps: float) -> None:
    """(H, W, 3) uint8 RGB frames as FFV1 in RGB (Matroska) that OpenCV and PyAV read back bit for bit;
    checked: a crop that does not read back as written is an error, not an input."""
    from fractions import Fraction

    import av

    with av.open(str(path), "w") as container:
        stream = container.add_stream("ffv1", rate=Fraction(fps).limit_denominator(1001))
        stream.width, stream.height, stream.pix_fmt = frames[0].shape[1], frames[0].shape[0], "bgr0"
        for rgb in frames:
            container.mux(stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")))
        container.mux(stream.encode(None))
    back = read_video(path)
    if len(back) != len(frames) or not all(np.array_equal(a, b) for a, b in zip(frames, back)):
        raise FdError(f"{path}: the lossless crop does not read back as written")


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
