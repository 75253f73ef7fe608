"""The face model sent beside the call's frames, within its --bitrate (``fd-send --paced-face``).

Sent before the first frame, a 256x256 face file of 10-18 KB (version 9) held the first whole picture
back by 25-29 s at 4 kbit/s (benchmarks/bench_call_start.py). Paced, the first frame goes at once and
the receiver draws the generic face; a preview of the face (codec/face_file/format.preview_face,
1.3-2.3 KB) and then the face itself follow in chunks as the rate leaves room, each drawn from the frame
after it completes. The picture layer, whose sender must draw what the receiver draws, starts once
the face is through and the last 2 seconds carried none of it (its first key then finds the rate's
window as at a call's start). On three dev clips' crops at 4 kbit/s the preview was drawn after
5.0-6.1 s (the face sent first: 18-22 s), the face itself after 31-38 s (README, "One-off bytes").

Over datagrams (``rounds``) a chunk may be lost and a receiver may join late, so the face goes round:
after its last chunk the first again, until the receiver's loss report (protocol/report.py) says it
holds it all; each report moves the next chunk on to the first byte it lacks, or back to it where
the receiver lacks the preview (one that joined late: it draws the speaker sooner). A receiver that
joins after the face is through and reports a face it lacks starts the rounds again. Without reports
(a one-way link, a sealed stream) the rounds go on for the whole call, so that whoever joins gets
the face within one.
"""

from facedeform.protocol.encoder import MODEL_CHUNK, PacketEncoder, stream_size
from facedeform.protocol.report import Report

#: A chunk carries a quarter of a second of the call's rate (at least LEAST_PIECE bytes, at most a
#: model chunk): each costs about 10 bytes of framing (4 of them its CRC-32), 8 % at 4 kbit/s.
PIECE_SECONDS = 0.25
LEAST_PIECE = 24
WINDOW = 2.0  # seconds over which the stream, chunks included, keeps within its rate
FRAMING = 10  # bytes a chunk adds to what it carries, about


class FacePacing:
    """The in-band model of ``encoder`` (``size`` bytes: the preview, then the face) in chunks within
    ``bitrate`` bit/s for the whole stream over frames ``fps`` a second. :meth:`step` takes the bits
    each frame's own packets cost, and what the stream sent over the frames of the last WINDOW seconds
    before it, and gives the chunks to send before them: what the frames leave of the rate, saved up
    to a chunk's worth, as far as the window leaves room. ``sealed``:
    packets are sealed (a sync byte each more); ``rounds``: over datagrams, round and round until the
    receiver reports the whole face held (:meth:`hear`); ``preview``: the first bytes, a preview face."""

    def __init__(self, encoder: PacketEncoder, size: int, bitrate: float, fps: float, sealed: bool = False,
                 rounds: bool = False, preview: int = 0) -> None:
        self._encoder, self._size, self._sealed, self._rounds, self._preview = encoder, size, sealed, rounds, preview
        self._piece = int(min(MODEL_CHUNK, max(LEAST_PIECE, bitrate * PIECE_SECONDS / 8)))
        self._window = window = max(1, round(WINDOW * fps))
        self._quiet = 0  # frames since the last chunk
        self._frame_bits = bitrate / fps
        self._window_bits = self._frame_bits * window
        #: bits the chunks may spend: what the frames left of the rate, within a chunk's worth either way
        #: (over UDP before any report the frames' copies alone can go over the rate for as long as no
        #: receiver reports: owed in full, that had held the face back 18 s after one joined 20 s in)
        self._credit = 0.0
        self.sent = 0  # bytes of the model sent, rounds included
        self._next = 0  # where the next chunk starts
        self._held: int | None = None  # the first byte the receiver last reported it lacks; None: no report
        self._lacking = 0  # reports in a row of a face lacking since it was through

    @property
    def done(self) -> bool:
        """Whether the whole model has been sent (over datagrams: the receiver reported it whole)."""
        if self._rounds:
            return self._held is not None and self._held >= self._size
        return self._next >= self._size

    def hear(self, report: Report | None) -> None:
        """Over datagrams, the receiver's newest report (None: none came since the last). Once the face is
        through, it takes two reports in a row of a face lacking to start the rounds again (a receiver
        that joined late, not one report that came out of order)."""
        if not self._rounds or report is None or report.face is None:
            return
        lacking = report.face < self._size
        self._lacking = self._lacking + 1 if lacking and self.done else 0
        if lacking and self.done and self._lacking < 2:
            return
        self._held = report.face
        if report.face < self._preview <= self._next:  # a receiver without the preview (one that joined late)
            self._next = report.face
        else:
            self._next = max(self._next, min(report.face, self._size))

    @property
    def drained(self) -> bool:
        """Whether the whole model has been sent and the last WINDOW seconds carried none of it: the
        picture layer's first key then finds the window as at a call's start."""
        return self.done and self._quiet >= self._window - 1

    def step(self, frame_bits: int, spent: float) -> list[bytes]:
        """The chunks to send before a frame whose own packets cost ``frame_bits``, where the frames of
        the WINDOW seconds before it cost ``spent``, chunks included."""
        most = 8.0 * (self._piece + FRAMING)
        self._credit = min(max(self._credit + self._frame_bits - frame_bits, -most), most)
        room = min(self._credit, self._window_bits - spent - frame_bits)
        chunks: list[bytes] = []
        while not self.done:
            if self._next >= self._size:  # another round, from the first byte the receiver lacks
                self._next = min(self._held or 0, self._size - 1)
            size = min(self._piece, self._size - self._next)
            if 8 * (size + FRAMING) > room:
                break
            chunk = self._encoder.model_chunk(self._next, size)
            bits = 8 * stream_size([chunk], self._sealed)
            room -= bits
            self._credit -= bits
            self._next += size
            self.sent += size
            chunks.append(chunk)
        self._quiet = 0 if chunks else self._quiet + 1
        return chunks
