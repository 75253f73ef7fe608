"""One receiving session: stream bytes in, frames out as soon as each packet is complete."""

import sys

import numpy as np

from codec.errors import BitstreamError
from codec.face_model import load_base_face
from protocol.stream import Damage, End, Frame, Header, StreamDecoder
from receiver.face_view import FaceView
from receiver.output import open_writer

CHUNK = 1 << 16


class ReceiveSession:
    """Decodes, renders and writes; frames already written survive a broken stream.

    Damage inside the stream is reported on stderr as it happens and concealed
    until the next keyframe; a stream that stops short raises once its last
    whole frame is written.
    """

    def __init__(self, target: str, size: tuple[int, int], stdout, warn=None) -> None:
        self._target, self._size, self._stdout = target, size, stdout
        self._warn = warn or (lambda line: print(f"fd-recv: warning: {line}", file=sys.stderr))
        self._decoder = StreamDecoder()
        self._writer = None
        self._view: FaceView | None = None
        self.decoded: list[Frame] = []

    def run(self, source) -> None:
        """Reads ``source`` (a binary file object) to its end, rendering every frame."""
        read = getattr(source, "read1", source.read)
        while chunk := read(CHUNK):
            for event in self._decoder.feed(chunk):
                self._handle(event)
        for event in self._decoder.close():
            if not isinstance(event, Damage):  # the end's damage is the truncation, raised below
                self._handle(event)
        if not self._decoder.ended:
            raise BitstreamError(f"truncated stream: it stopped after {len(self.decoded)} frames, "
                                 "before its end mark")

    def _handle(self, event) -> None:
        if isinstance(event, Header):
            self._view = FaceView(event, load_base_face(), self._size)
            self._writer = open_writer(self._target, event.fps, self._size, self._stdout)
        elif isinstance(event, Frame):
            self._writer.write(self._view.render(event.params))
            self.decoded.append(event)
        elif isinstance(event, Damage):
            self._warn(f"damaged stream at frame {event.seq} ({event.reason}): "
                       "holding the last frame until the next keyframe")
        elif isinstance(event, End) and event.frames != len(self.decoded):
            raise BitstreamError(f"stream says {event.frames} frames, {len(self.decoded)} arrived")

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()

    def summary(self, seconds: float) -> str:
        n = len(self.decoded)
        concealed = sum(f.concealed for f in self.decoded)
        return (f"{n} frames rendered ({concealed} concealed, {self._decoder.stats.damaged} damage reports), "
                f"{n / max(seconds, 1e-9):.1f} frames/s")

    def write_dump(self, path: str) -> None:
        header = self._decoder.header
        np.savez_compressed(
            path, params=np.array([f.params for f in self.decoded]), names=np.array(header.names),
            seq=np.array([f.seq for f in self.decoded]), face_seen=np.array([f.face_seen for f in self.decoded]),
            concealed=np.array([f.concealed for f in self.decoded]),
            interpolated=np.array([f.interpolated for f in self.decoded]), fps=header.fps)
