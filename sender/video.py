"""Frames from a video file, one at a time, with errors a user can act on."""

import os
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from codec.errors import InputError

# FFmpeg inside OpenCV would print its own complaints about a bad file; ours is one line.
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")


class VideoSource:
    """Reads a video file with OpenCV; ``fps`` and ``size`` are known on opening.

    Raises :class:`InputError` for a missing file or one that holds no video.
    """

    def __init__(self, path: str | Path) -> None:
        path = Path(path)
        if not path.exists():
            raise InputError(f"{path}: no such file")
        if not path.is_file():
            raise InputError(f"{path}: not a file")
        self._cap = cv2.VideoCapture(str(path))
        ok, first = self._cap.read() if self._cap.isOpened() else (False, None)
        if not ok or first is None or first.ndim != 3:
            self._cap.release()
            raise InputError(f"{path}: not a video OpenCV can read")
        self._first: np.ndarray | None = first
        fps = self._cap.get(cv2.CAP_PROP_FPS)
        self.fps = float(fps) if 0 < fps < 1000 else 25.0
        self.size = (first.shape[1], first.shape[0])  # (width, height)
        self.path = path

    def frames(self) -> Iterator[np.ndarray]:
        """(H, W, 3) uint8 BGR frames, the first included, until the file ends."""
        if self._first is not None:
            first, self._first = self._first, None
            yield first
        while True:
            ok, frame = self._cap.read()
            if not ok:
                self._cap.release()
                return
            yield frame
