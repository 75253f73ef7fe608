"""The face model sent beside the call's frames, within its --bitrate (``fd-send --paced-face``).

Sent before the first frame, a 256x256 face file of 10-18 KB (version 9) held the first whole picture
back by 25-29 s at 4 kbit/s (benchmarks/bench_call_start.py). Paced, the first frame goes at once and
the receiver draws the generic face; a preview of the face (codec/face_file/format.preview_face,
1.3-2.3 KB) and then the face itself follow in chunks as the rate leaves room, each drawn from the frame
after it completes. The picture layer, whose sender must draw what the receiver draws, starts once
the face is through and the last 2 seconds carried none of it (its first key then finds the rate's
window as at a call's start). On three dev clips' crops at 4 kbit/s the preview was drawn after
5.0-6.1 s (the face sent first: 18-22 s), the face itself after 31-38 s (README, "One-off bytes").
"""

from collections import deque

from facedeform.protocol.encoder import MODEL_CHUNK, PacketEncoder, stream_size

#: A chunk carries a quarter of a second of the call's rate (at least LEAST_PIECE bytes, at most a
#: model chunk): each costs about 10 bytes of framing (4 of them its CRC-32), 8 % at 4 kbit/s.
PIECE_SECONDS = 0.25
LEAST_PIECE = 24
WINDOW = 2.0  # seconds over which the stream, chunks included, keeps within its rate
FRAMING = 10  # bytes a chunk adds to what it carries, about


class FacePacing:
    """The in-band model of ``encoder`` (``size`` bytes: the preview, then the face) in chunks within
    ``bitrate`` bit/s for the whole stream over frames ``fps`` a second. :meth:`step` takes the bits
    each frame's own packets cost and gives the chunks to send before them: what the frames leave of
    the rate, saved up to a chunk's worth, as far as the last WINDOW seconds leave room. ``sealed``:
    packets are sealed (a sync byte each more)."""

    def __init__(self, encoder: PacketEncoder, size: int, bitrate: float, fps: float, sealed: bool = False) -> None:
        self._encoder, self._size, self._sealed = encoder, size, sealed
        self._piece = int(min(MODEL_CHUNK, max(LEAST_PIECE, bitrate * PIECE_SECONDS / 8)))
        self._window = window = max(1, round(WINDOW * fps))
        self._quiet = 0  # frames since the last chunk
        self._frame_bits = bitrate / fps
        self._window_bits = self._frame_bits * window
        self._credit = 0.0  # bits the chunks may spend: what the frames left of the rate, at most a chunk's
        #: bits of the last frames sent, chunks included: what the picture layer starts from
        self.recent: deque[int] = deque(maxlen=window - 1)
        self.sent = 0  # bytes of the model sent

    @property
    def done(self) -> bool:
        """Whether the whole model has been sent."""
        return self.sent >= self._size

    @property
    def drained(self) -> bool:
        """Whether the whole model has been sent and the last WINDOW seconds carried none of it: the
        picture layer's first key then finds the window as at a call's start."""
        return self.done and self._quiet >= self._window - 1

    def step(self, frame_bits: int) -> list[bytes]:
        """The chunks to send before a frame whose own packets cost ``frame_bits``."""
        self._credit = min(self._credit + self._frame_bits - frame_bits, 8.0 * (self._piece + FRAMING))
        room = min(self._credit, self._window_bits - sum(self.recent) - frame_bits)
        chunks: list[bytes] = []
        while not self.done:
            size = min(self._piece, self._size - self.sent)
            if 8 * (size + FRAMING) > room:
                break
            chunk = self._encoder.model_chunk(self.sent, size)
            bits = 8 * stream_size([chunk], self._sealed)
            room -= bits
            self._credit -= bits
            self.sent += size
            chunks.append(chunk)
        self.recent.append(frame_bits + 8 * stream_size(chunks, self._sealed))
        self._quiet = 0 if chunks else self._quiet + 1
        return chunks
