"""Frame sinks: an H.264 file through PyAV, or YUV4MPEG2 (Y4M) on any binary stream.

Y4M is the plain format that ffmpeg, mpv and x264 read from a pipe
(``fd-recv -o - | ffmpeg -i - ...``): it needs no container. To watch a call,
fd-recv --serve shows it in a browser (receiver/viewer.py).
"""

from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np

from facedeform.common.errors import InputError

VIDEO_SUFFIXES = (".mp4", ".mkv", ".mov")


def _rate(fps: float) -> Fraction:
    return Fraction(fps).limit_denominator(1001)


class Y4mWriter:
    """Writes (H, W, 3) uint8 RGB frames as 4:2:0 Y4M (BT.601 full range, "C420jpeg")."""

    def __init__(self, stream, fps: float, size: tuple[int, int], owns_stream: bool = False) -> None:
        w, h = size
        if w % 2 or h % 2:
            raise InputError(f"Y4M output needs an even width and height, not {w}x{h}")
        rate = _rate(fps)
        self._stream = stream
        self._owns_stream = owns_stream
        self._stream.write(f"YUV4MPEG2 W{w} H{h} F{rate.numerator}:{rate.denominator} Ip A1:1 C420jpeg\n".encode())

    def write(self, rgb: np.ndarray) -> None:
        self._stream.write(b"FRAME\n" + cv2.cvtColor(rgb, cv2.COLOR_RGB2YUV_I420).tobytes())
        self._stream.flush()

    def close(self) -> None:
        self._stream.flush()
        if self._owns_stream:
            self._stream.close()


class VideoFileWriter:
    """Writes (H, W, 3) uint8 RGB frames as H.264 (yuv420p) in an mp4/mkv/mov file that common players open."""

    def __init__(self, path: str | Path, fps: float, size: tuple[int, int]) -> None:
        import av

        w, h = size
        if w % 2 or h % 2:
            raise InputError(f"H.264 output needs an even width and height, not {w}x{h}")
        try:
            self._container = av.open(str(path), mode="w")
        except OSError as exc:
            raise InputError(f"{path}: cannot write ({exc.strerror or exc})") from None
        self._stream = self._container.add_stream("libx264", rate=_rate(fps))
        self._stream.width, self._stream.height = w, h
        self._stream.pix_fmt = "yuv420p"
        self._stream.options = {"crf": "18", "preset": "veryfast"}
        self._av = av

    def write(self, rgb: np.ndarray) -> None:
        frame = self._av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
        for packet in self._stream.encode(frame):
            self._container.mux(packet)

    def close(self) -> None:
        for packet in self._stream.encode():
            self._container.mux(packet)
        self._container.close()


def open_writer(target: str, fps: float, size: tuple[int, int], stdout):
    """A writer for ``target``: ``-`` (Y4M on ``stdout``), ``*.y4m``, or a video file by its suffix."""
    if target == "-":
        return Y4mWriter(stdout, fps, size)
    suffix = Path(target).suffix.lower()
    if suffix == ".y4m":
        try:
            return Y4mWriter(open(target, "wb"), fps, size, owns_stream=True)
        except OSError as exc:
            raise InputError(f"{target}: cannot write ({exc.strerror})") from None
    if suffix in VIDEO_SUFFIXES:
        return VideoFileWriter(target, fps, size)
    raise InputError(f"{target}: unknown output type (use .mp4, .mkv, .mov, .y4m or -)")
