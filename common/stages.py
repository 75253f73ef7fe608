"""What each stage of the chain takes and gives, as small structural interfaces.

frames -> landmarks -> parameters -> bits -> parameters -> pixels: a
:class:`Source` gives frames, a :class:`Tracker` their landmarks, the
estimator (``sender.analysis.FaceAnalyser``) parameters, the encoder
(``protocol.encoder.PacketEncoder``, one kind) packets, a :class:`Decoder` events (``protocol.events``), a :class:`View`
pixels, and a :class:`Sink` takes them. Any object with these members is one
(``typing.Protocol``): tests pass fakes, and mypy checks the real ones where
they are used.
"""

from collections.abc import Iterator
from typing import Any, Protocol

import numpy as np


class Source(Protocol):
    """Frames of a talking face: (H, W, 3) uint8 BGR, at ``fps``; ``size`` is (width, height);
    ``length`` the frame count when known (progress only), else None."""

    fps: float
    size: tuple[int, int]
    length: int | None

    def frames(self) -> Iterator[np.ndarray]: ...


class Tracker(Protocol):
    """One frame -> (468, 3) float32 landmarks in pixels (x right, y down, z away), None without a face."""

    def track(self, frame_bgr: np.ndarray) -> np.ndarray | None: ...


class Decoder(Protocol):
    """Bytes in any chunking -> events; :meth:`close` at the stream's end. ``header``: the
    stream's header once it arrived (else None); ``ended``: its end mark arrived; ``stats``:
    counters (``protocol.events.Stats``)."""

    @property
    def header(self) -> Any: ...

    @property
    def ended(self) -> bool: ...

    @property
    def stats(self) -> Any: ...

    def feed(self, data: bytes) -> list: ...

    def close(self) -> list: ...

    def hold_model(self) -> None:
        """The receiver holds the stream's face model already: its chunks are passed over."""


class StreamSource(Protocol):
    """Where a receiver's stream comes from (a file, stdin, a socket: ``receiver.transport``):
    batches of the decoder's events with the ``time.perf_counter()`` at which their bytes arrived.
    ``size``: total bytes if known (progress), ``consumed``: bytes read so far; ``timed_out``: a
    socket went quiet before the end mark; ``no_stream()``: why nothing decodable arrived."""

    @property
    def decoder(self) -> Decoder: ...

    size: int | None
    consumed: int
    timed_out: bool

    def batches(self) -> Iterator[tuple[list, float]]: ...

    def no_stream(self) -> str: ...


class View(Protocol):
    """(k,) parameters of the stream's layout (of frame ``seq``) -> one (H, W, 3) uint8 RGB picture."""

    def render(self, params: np.ndarray, seq: int | None = None) -> np.ndarray: ...


class Sink(Protocol):
    """Where pictures go: a video file, stdout, a browser."""

    def write(self, rgb: np.ndarray) -> None: ...

    def close(self) -> None: ...
