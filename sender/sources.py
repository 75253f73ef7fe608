"""Where frames come from: a video file, an image sequence or a camera.

Every source has ``fps``, ``size`` (width, height) and ``frames()`` yielding
(H, W, 3) uint8 BGR frames, and raises :class:`InputError` with a one-line
message when it cannot be used.
"""

import os
import re
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from facedeform.common.errors import InputError

# FFmpeg inside OpenCV would print its own complaints about a bad file; ours is one line.
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm"}
DEFAULT_FPS = 25.0


def _rate(fps: float) -> float:
    return float(fps) if 0 < fps < 1000 else DEFAULT_FPS


class VideoSource:
    """A video file read with OpenCV, or with PyAV when OpenCV cannot open it."""

    def __init__(self, path: str | Path) -> None:
        path = Path(path)
        if not path.exists():
            raise InputError(f"{path}: no such file")
        if not path.is_file():
            raise InputError(f"{path}: not a file")
        self.path = path
        cap = cv2.VideoCapture(str(path))
        ok, first = cap.read() if cap.isOpened() else (False, None)
        if ok and first is not None and first.ndim == 3:
            self._frames = self._opencv(cap, first)
            fps = cap.get(cv2.CAP_PROP_FPS)
            count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
            self.length = count if count > 0 else None  # for progress only: containers may be wrong
        else:
            cap.release()
            first, fps, self._frames = self._pyav(path)
            self.length = None
        self.fps = _rate(fps)
        self.size = (first.shape[1], first.shape[0])

    @staticmethod
    def _opencv(cap, first: np.ndarray) -> Iterator[np.ndarray]:
        yield first
        while True:
            ok, frame = cap.read()
            if not ok:
                cap.release()
                return
            yield frame

    @staticmethod
    def _pyav(path: Path) -> tuple[np.ndarray, float, Iterator[np.ndarray]]:
        import av

        try:
            container = av.open(str(path))
            stream = container.streams.video[0]
            decoded = (f.to_ndarray(format="bgr24") for f in container.decode(stream))
            first = next(decoded)
        except (av.error.FFmpegError, IndexError, StopIteration, UnicodeDecodeError):
            raise InputError(f"{path}: not a video OpenCV or PyAV can read") from None

        def frames() -> Iterator[np.ndarray]:
            yield first
            yield from decoded
            container.close()

        return first, float(stream.average_rate or 0), frames()

    def frames(self) -> Iterator[np.ndarray]:
        """Every frame, the first included, until the file ends."""
        return self._frames


class ImageSequence:
    """Numbered images: a directory (files in name order) or a printf pattern like ``frames/%04d.png``."""

    def __init__(self, spec: str, fps: float = DEFAULT_FPS) -> None:
        if "%" in spec:
            self.paths = self._numbered(spec)
        else:
            folder = Path(spec)
            self.paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not self.paths:
            raise InputError(f"{spec}: no images found")
        first = self._read(self.paths[0])
        self.fps = _rate(fps)
        self.size = (first.shape[1], first.shape[0])
        self.length = len(self.paths)

    @staticmethod
    def _numbered(pattern: str) -> list[Path]:
        if not re.fullmatch(r"[^%]*%0?\d*d[^%]*", pattern):
            raise InputError(f"{pattern}: a pattern takes one integer field such as %04d")
        start = next((i for i in range(2) if Path(pattern % i).exists()), None)
        paths: list[Path] = []
        while start is not None and Path(pattern % (start + len(paths))).exists():
            paths.append(Path(pattern % (start + len(paths))))
        return paths

    @staticmethod
    def _read(path: Path) -> np.ndarray:
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            raise InputError(f"{path}: not an image OpenCV can read")
        return image

    def frames(self) -> Iterator[np.ndarray]:
        for path in self.paths:
            yield self._read(path)


class CameraSource:
    """A live camera by OpenCV index; frames until the camera stops or the user interrupts."""

    def __init__(self, index: int) -> None:
        level = cv2.utils.logging.getLogLevel()
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)  # our message is the one line
        try:
            self._cap = cv2.VideoCapture(index)
            ok, first = self._cap.read() if self._cap.isOpened() else (False, None)
        finally:
            cv2.utils.logging.setLogLevel(level)
        if not ok or first is None:
            self._cap.release()
            raise InputError(f"camera {index} not available")
        self._first: np.ndarray | None = first
        self.fps = _rate(self._cap.get(cv2.CAP_PROP_FPS))
        self.size = (first.shape[1], first.shape[0])
        self.length = None  # live: no end to show progress toward

    def frames(self) -> Iterator[np.ndarray]:
        if self._first is not None:
            first, self._first = self._first, None
            yield first
        while True:
            ok, frame = self._cap.read()
            if not ok:
                self._cap.release()
                return
            yield frame


class LoopedSource:
    """A file or image sequence played over and over until ``seconds`` of input (at its frame rate)
    have gone by: a long call from a short clip, for benchmarks of memory and latency."""

    def __init__(self, spec: str, seconds: float) -> None:
        first = open_source(spec)
        self._spec, self.fps, self.size = spec, first.fps, first.size
        self.length = max(1, round(seconds * self.fps))
        self._first = first

    def frames(self) -> Iterator[np.ndarray]:
        source, count = self._first, 0
        while True:
            looped = 0
            for frame in source.frames():
                if count == self.length:
                    return
                yield frame
                count, looped = count + 1, looped + 1
            if not looped:
                raise InputError(f"{self._spec}: no frames to loop")
            source = open_source(self._spec)


class PacedSource:
    """Another source's frames handed over no faster than its frame rate, as a camera delivers them:
    frame i at ``start + i / fps``, where start is when the first frame is read (``fd-send
    --realtime``); a frame that takes longer to read comes as soon as it is read."""

    def __init__(self, source) -> None:
        self._source = source
        self.fps, self.size, self.length = source.fps, source.size, source.length

    def frames(self) -> Iterator[np.ndarray]:
        start = None
        for index, frame in enumerate(self._source.frames()):
            now = time.monotonic()
            if start is None:
                start = now
            due = start + index / self.fps
            if due > now:
                time.sleep(due - now)
            yield frame


def open_source(spec: str | None = None, camera: int | None = None, fps: float = DEFAULT_FPS):
    """A camera by index, an image sequence (a directory or a %d pattern) or a video file."""
    if camera is not None:
        return CameraSource(camera)
    if spec is None:
        raise InputError("give an input file or a camera")
    if "%" in spec or Path(spec).is_dir():
        return ImageSequence(spec, fps)
    return VideoSource(spec)
