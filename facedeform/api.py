"""The library API: enrol a face, encode a video to stream bytes, decode stream bytes to frames.

Three verbs over iterators, each a thin call into the same sessions the
command-line tools run, so a stream made here is byte for byte the one fd-send
writes with the same settings, and frames decoded here are the ones fd-recv
draws. Frames are (H, W, 3) uint8 RGB arrays both ways. Mistakes in the
arguments raise ValueError or TypeError; a video, face or stream that cannot
be used raises :class:`facedeform.common.errors.FdError` (its message is one
line); damage inside a stream is reported to ``on_damage`` and concealed.
"""

import logging
import os
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from os import PathLike
from pathlib import Path

import numpy as np

from facedeform.codec.face_file.format import Face
from facedeform.common.limits import MAX_SIDE

__all__ = ["Face", "decode", "encode", "enroll"]

log = logging.getLogger("facedeform")


def enroll(video: str | PathLike, **options) -> Face:
    """The face model of the person in ``video`` (a video file, an image directory or a %d
    pattern), to share before a call: their mesh, reference picture, open mouth and motion
    basis. Options (``sender.enrolment.enroll_face``): frame, seconds, motion, motion_over,
    motion_seconds, picture, texture_size, budget. ``Face.save(path)`` writes what fd-enroll writes."""
    from facedeform.sender.enrolment import enroll_face

    return enroll_face(_path(video, "video"), **options).face


def encode(video: str | PathLike | Iterable[np.ndarray], face: Face | str | PathLike | None = None, *,
           fps: float = 25.0, key: bytes | None = None, **options) -> Iterator[bytes]:
    """The stream of ``video``, as fd-send writes it to a file, in pieces as frames are analysed:
    the header once a face is seen, then the packets of each frame, then the end mark.

    video: a path, or an iterable of (H, W, 3) uint8 RGB frames at ``fps``; face: the person's
    face model (a :class:`Face` or a path; None: the generic face); key: 32 bytes
    (``common.keys``) to seal every packet with; options: ``sender.config.SendConfig``'s fields
    (quality 1-5 or bitrate in bit/s as fd-send's --quality and --bitrate, or a quantiser level;
    layout, dead_zone, rule, ...).
    """
    from facedeform.sender.config import SendConfig
    from facedeform.sender.session import SendSession

    config = SendConfig(key=key, **options)
    if face is not None and not isinstance(face, Face):
        face = Face.load(_path(face, "face"), key)
    source = _path(video, "video") if isinstance(video, str | PathLike) else _FrameSource(video, fps)
    session = SendSession(source, config, face=face)
    try:
        yield from session.stream()
    finally:  # also when the caller stops early
        session.close()


def decode(stream: bytes | str | PathLike | Iterable[bytes], face: Face | str | PathLike | None = None, *,
           look: str | None = None, size: tuple[int, int] | None = None, key: bytes | None = None,
           on_damage: Callable[[str], None] | None = None) -> Iterator[np.ndarray]:
    """The frames of a stream as fd-recv draws them, (H, W, 3) uint8 RGB, each as soon as the
    bytes that complete it have been read.

    stream: the whole stream as bytes, a stream file's path, or an iterable of byte chunks in any
    cutting (``encode``'s output, a socket's reads); face: the sender's face model when the
    stream names it without carrying it (a :class:`Face` or a path); look: "picture", "face" or
    "shaded" (None: the most the face allows); size: (width, height), None for the source's;
    key: the stream's pre-shared key; on_damage(message): each damage report (default: logged
    as a warning on the "facedeform" logger). A stream cut short raises BitstreamError after
    its last whole frame was yielded.
    """
    from facedeform.receiver.face_view import LOOKS
    from facedeform.receiver.session import ReceiveSession
    from facedeform.receiver.transport import ByteSource, open_file

    if look is not None and look not in LOOKS:
        raise ValueError(f"look must be one of {', '.join(LOOKS)}, not {look!r}")
    if size is not None and not (len(size) == 2 and all(isinstance(s, int) and 16 <= s <= MAX_SIDE for s in size)):
        raise ValueError(f"size must be (width, height), each 16 to {MAX_SIDE}, not {size!r}")
    if face is not None and not isinstance(face, Face):
        face = Face.load(_path(face, "face"), key)
    pending: deque[np.ndarray] = deque()
    session = ReceiveSession(lambda fps, wh: [_Collect(pending)], size, None if face is None else face.model,
                             "face", look=look, warn=on_damage or log.warning)
    if isinstance(stream, str | PathLike):
        path = _path(stream, "stream")
        source = open_file(path if path != "-" else os.path.join(".", path), None, key)  # a file, not stdin
    else:
        source = ByteSource(_reader(stream), key=key)
    session.source = source
    try:
        for events, arrived in source.batches():
            session.handle(events, arrived)
            while pending:
                yield pending.popleft()
        session.finish()
    finally:
        session.close()
    yield from pending


class _FrameSource:
    """RGB frames from the caller as a ``sender.sources`` source (BGR, as OpenCV's)."""

    length: int | None = None

    def __init__(self, frames: Iterable[np.ndarray], fps: float) -> None:
        if not (isinstance(fps, int | float) and 0.1 <= fps <= 1000):
            raise ValueError(f"fps must be 0.1 to 1000, not {fps!r}")
        self.fps = float(fps)
        self._frames = iter(frames)
        self._first = self._check(next(self._frames, None))
        self.size = (self._first.shape[1], self._first.shape[0])

    @staticmethod
    def _check(frame) -> np.ndarray:
        if frame is None:
            raise ValueError("no frames to encode")
        frame = np.asarray(frame)
        if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
            raise ValueError(f"frames must be (H, W, 3) uint8 RGB arrays, not {frame.dtype} {frame.shape}")
        return frame

    def frames(self) -> Iterator[np.ndarray]:
        yield np.ascontiguousarray(self._first[..., ::-1])
        for frame in self._frames:
            yield np.ascontiguousarray(self._check(frame)[..., ::-1])


class _Collect:
    """A sink that keeps each drawn frame until ``decode`` yields it."""

    def __init__(self, pending: deque | list) -> None:
        self._pending = pending

    def write(self, rgb: np.ndarray) -> None:
        self._pending.append(rgb.copy())

    def close(self) -> None:
        pass


def _reader(stream) -> Callable[[int], bytes]:
    """read(n) over the stream's bytes, whole or in chunks (n is a hint)."""
    if isinstance(stream, bytes | bytearray | memoryview):
        stream = [bytes(stream)]
    elif not isinstance(stream, Iterable):
        raise TypeError(f"stream must be bytes, a path or an iterable of bytes, not {type(stream).__name__}")
    chunks = iter(stream)

    def read(n: int) -> bytes:
        for chunk in chunks:
            if not isinstance(chunk, bytes | bytearray | memoryview):
                raise TypeError(f"stream chunks must be bytes, not {type(chunk).__name__}")
            if chunk:
                return bytes(chunk)
        return b""

    return read


def _path(value, what: str) -> str:
    if not isinstance(value, str | PathLike):
        raise TypeError(f"{what} must be a path, not {type(value).__name__}")
    return str(Path(value))
