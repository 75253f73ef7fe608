"""One receiving session: decoded events in, frames rendered and written as soon as each packet is complete
(or, where the stream's picture layer draws a frame from its next video frame too, as soon as that is)."""

import math
import sys
import time
from collections import deque
from collections.abc import Callable
from fractions import Fraction

import numpy as np

from facedeform.codec.face_file.format import decode_face
from facedeform.codec.model.face_model import BaseFace, load_base_face
from facedeform.common.cli import fitted
from facedeform.common.errors import BitstreamError, InputError
from facedeform.common.npz import NpzAppender
from facedeform.common.stages import Sink, StreamSource, View
from facedeform.protocol.stream import Damage, End, Frame, Header, Model, Picture, Stats
from facedeform.receiver.face_cache import FaceCache
from facedeform.receiver.face_view import PictureView, default_look, open_view, output_size

LATENCY_WINDOW = 10_000  # frames: latency statistics cover the last 6-7 minutes at 25 fps


class ReceiveSession:
    """Chooses the face, renders every frame, writes it to the sinks, and keeps statistics.

    open_sinks(fps, (width, height)) -> list of objects with write((H, W, 3)
    uint8 RGB) and close(), called once the header gives the rate and the face
    is known; size: output (width, height), None for the source's (the header's),
    else face_view.output_size's, a height of 0 for the height that keeps its proportions
    (common.cli.fitted); face: the model the user
    gave (``--face``), whose id must be the stream's; without it the model the
    stream carries, else the generic face; look: one of face_view.LOOKS, None
    for the most the face allows (face_view.default_look). fps: output rate (None: the
    stream's), met by repeating or dropping frames; dump: a .npz path for the decoded parameters,
    written as frames pass and finished by :meth:`close`; faces: a folder of face models by id
    (receiver.face_cache) that stands in for ``--face`` when it holds the stream's and keeps the
    one the stream carries. Damage is reported through
    ``warn`` and concealed until the next keyframe; frames already written
    survive a broken stream. Memory does not grow with the call: counters, and the latency
    of the last :data:`LATENCY_WINDOW` frames.
    """

    def __init__(self, open_sinks: Callable[[float, tuple[int, int]], list[Sink]], size: tuple[int, int] | None,
                 face: BaseFace | None = None,
                 face_name: str = "--face", fps: float | None = None, warn=None, look: str | None = None,
                 dump: str | None = None, faces: FaceCache | None = None) -> None:
        self._open_sinks, self._size, self._given, self._given_name = open_sinks, size, face, face_name
        self._faces = faces
        self._fps, self._look, self._out_fps = fps, look, 0.0
        self.look: str | None = None
        self._warn = warn or (lambda line: print(f"fd-recv: warning: {line}", file=sys.stderr))
        self._sinks: list = []
        self._header_seen: Header | None = None
        self._view: View | None = None
        self._ratio = Fraction(1)
        self.source: StreamSource | None = None
        #: the counters the picture layer's losses go into: the source's decoder's once :meth:`run` reads
        #: one (its loss reports carry them to the sender), until then the session's own
        self.counts = Stats()
        self.face_kind: str | None = None
        self.face_id: str | None = None
        self.frames = self.concealed = self.interpolated = self.written = self.layer_packets = 0
        #: bytes the source had read when the first frame arrived: the header, an in-band model
        self.bytes_before_frames = 0
        #: seconds from the arrival of a frame's packet to its output, for the last LATENCY_WINDOW frames
        self.latency: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self.latency_max = 0.0
        self._dump_path = dump
        self._dump: NpzAppender | None = None
        #: (frame, parameters, output frames it makes, its packet's arrival) of frames decoded, not yet
        #: drawn: the picture layer's next video frame is awaited (header.ahead, VideoLayer.ready)
        self._waiting: deque[tuple[int, np.ndarray, int, float]] = deque()

    def run(self, source: StreamSource, on_batch=None) -> None:
        """Consumes ``source`` (receiver.transport) to its end; ``on_batch()`` after each arrival.

        Raises BitstreamError for a byte stream cut short (after writing what
        arrived); a socket that went quiet ends with a warning instead.
        """
        self.source = source
        self.counts = source.decoder.stats
        for events, arrived in source.batches():
            self.handle(events, arrived)
            if on_batch is not None:
                on_batch()
        self.finish()

    def handle(self, events: list, arrived: float) -> None:
        """Renders and writes what one batch of decoded events completes (``arrived``: its
        ``time.perf_counter()``, for the latency)."""
        for event in events:
            self._handle(event, arrived)

    def finish(self) -> None:
        """Once ``self.source`` has ended: raises BitstreamError if it held no stream or was cut
        short before its end mark; a socket that went quiet is a warning."""
        source = self.source
        if source is None:
            raise RuntimeError("finish() before a source was read")
        self._draw_waiting()
        if source.decoder.header is None:
            raise BitstreamError(source.no_stream())
        if source.decoder.header.preview_size and self.face_kind in ("generic", "preview"):
            self._warn(f"the call ended before its face model had come whole: drawn with the "
                       f"{'preview' if self.face_kind == 'preview' else 'generic face'}")
        if source.decoder.ended:
            return
        if source.timed_out:
            self._warn(f"nothing arrived for a while: ending after {self.frames} frames, "
                       "without the stream's end mark")
        else:
            raise BitstreamError(f"truncated stream: it stopped after {self.frames} frames, "
                                 "before its end mark")

    def _handle(self, event, arrived: float) -> None:
        if isinstance(event, Header):
            self._start(event)
        elif isinstance(event, Model):
            self._model(event)
        elif isinstance(event, Frame):
            self._frame(event, arrived)
        elif isinstance(event, Picture):
            self._picture_layer(event)
        elif isinstance(event, Damage):
            self._warn(f"damaged stream at frame {event.seq} ({event.reason}): "
                       "holding the last frame until the next keyframe")
        elif isinstance(event, End) and event.frames != self.frames:
            raise BitstreamError(f"stream says {event.frames} frames, {self.frames} arrived")

    def _picture_layer(self, event: Picture) -> None:
        """The picture layer's payload: handed to a view that draws the whole picture; one that
        cannot be used is reported, the model's picture drawn alone until the layer's next key."""
        view = self._layered(self._view)
        if view is None:
            return
        if view.layer.take(event.seq, event.data):
            self.layer_packets += 1
        else:
            self.counts.layer_lost += 1
            self._warn(f"picture layer lost or damaged at frame {event.seq}: "
                       "the model's picture alone until its next key")

    def _layered(self, view: View | None) -> PictureView | None:
        """``view`` if it draws the picture layer: a whole picture, not a preview (the layer draws over
        the face itself)."""
        return view if isinstance(view, PictureView) and self.face_kind != "preview" else None

    def _start(self, header: Header) -> None:
        self._header_seen = header
        out = self._out_fps = self._fps or header.fps
        self._ratio = Fraction(out).limit_denominator(1001) / Fraction(header.fps).limit_denominator(1001)
        if self._given is None and self._faces is not None:
            held = self._faces.get(header.face_id, self._warn)
            if held is not None:
                self._given, self._given_name = held, f"--faces {self._faces.folder}"
        if self._given is not None:
            if header.face_id != self._given.content_id:
                raise InputError(f"{self._given_name} is face model {self._given.content_id[:12]}, "
                                 f"the stream was made for {header.face_id[:12]}")
            self._show(self._given, "file")
            if self.source is not None:  # its chunks in the stream are passed over, and reported held
                self.source.decoder.hold_model()
        elif not header.model_size:
            self._show(load_base_face(), "generic")
        elif header.preview_size:  # a paced face: the generic face until its preview has come
            self._show(load_base_face(), "generic", check_id=False)
        # else: the model follows in-band, before the first frame

    @property
    def _header(self) -> Header:
        """The stream's header, which comes before its model and frames."""
        if self._header_seen is None:
            raise BitstreamError("a model or frame before the stream's header")
        return self._header_seen

    def _model(self, event: Model) -> None:
        """The stream's face model, drawn from the next frame on unless the user gave theirs; a
        preview only until then (the decoder hands each over once)."""
        if self._given is not None:
            return
        if event.preview:  # only a first look: one that cannot be read leaves the generic face
            try:
                preview = decode_face(event.data, "the stream's preview face")
            except InputError as exc:
                self._warn(f"{exc}: drawing the generic face until the face model has come")
                return
            self._show(preview, "preview", check_id=False)
            return
        face = decode_face(event.data, "the stream's face model")
        if face.content_id != self._header.face_id:
            raise BitstreamError("the stream's face model does not match the face id in its header")
        if self._faces is not None:
            self._faces.keep(event.data, self._warn)
        self._show(face, "stream")

    def _show(self, face: BaseFace, kind: str, check_id: bool = True) -> View:
        self._draw_waiting()  # with the view that decoded them
        look = self._look or default_look(face)
        if not check_id and face.picture is None and look == "picture":
            look = "shaded"  # the in-band model was lost, and its picture with it
        if look == "face" and face.texture is None and face.picture is None:
            self._warn("--look face: this face model has no texture, so it is drawn shaded, as --look shaded")
            look = "shaded"
        natural = output_size(self._header, face, look)
        size = natural if self._size is None else fitted(self._size, natural)
        self._view = view = open_view(look, self._header, face, size, check_id)
        view.render(np.zeros(len(self._header.names)))  # compile and warm up before frames arrive
        self.face_kind, self.face_id, self.look = kind, face.content_id, look
        if not self._sinks:
            self._sinks = self._open_sinks(self._out_fps, size)
        return view

    def _frame(self, frame: Frame, arrived: float) -> None:
        view = self._view
        if view is None:  # a datagram of the in-band model was lost
            self._warn("the stream's face model did not arrive whole: drawing the generic face")
            view = self._show(load_base_face(), "generic", check_id=False)
        if not self.frames and self.source is not None:
            self.bytes_before_frames = self.source.consumed
        self.frames += 1
        self.concealed += frame.concealed
        self.interpolated += frame.interpolated
        if self._dump_path is not None:
            if self._dump is None:
                self._dump = decoded_dump(self._dump_path, len(self._header.names))
            self._dump.add(params=frame.params, seq=frame.seq, face_seen=frame.face_seen,
                           concealed=frame.concealed, interpolated=frame.interpolated)
        layered = self._layered(view)
        if layered is not None and not layered.advance(frame.params, frame.seq, exact=not frame.concealed):
            self.counts.layer_lost += 1
            self._warn(f"picture layer lost at frame {frame.seq}: the model's picture alone until its next key")
        # output frames whose time falls in this frame's interval: 1 at the stream's rate
        repeats = math.ceil((frame.seq + 1) * self._ratio) - math.ceil(frame.seq * self._ratio)
        self._waiting.append((frame.seq, frame.params, repeats, arrived))
        self._draw_waiting(frame.seq)

    def _draw_waiting(self, latest: int | None = None) -> None:
        """Draws and writes the frames waiting that can be drawn now that frame ``latest`` has been
        decoded (None: all of them, the stream having ended or its view changing)."""
        view = self._view
        layer = None if view is None or (layered := self._layered(view)) is None else layered.layer
        while self._waiting:
            seq, params, repeats, arrived = self._waiting[0]
            if latest is not None and layer is not None and not layer.ready(seq, latest):
                return
            self._waiting.popleft()
            if not repeats or view is None:
                continue
            image = view.render(params, seq)
            for _ in range(repeats):
                for sink in self._sinks:
                    sink.write(image)
            self.written += repeats
            took = time.perf_counter() - arrived
            self.latency.append(took)
            self.latency_max = max(self.latency_max, took)

    def close(self) -> None:
        """Writes the frames still waiting, closes the sinks and finishes the dump (none is written if no
        frame arrived)."""
        try:
            self._draw_waiting()
        finally:
            for sink in self._sinks:
                sink.close()
            if self._dump is not None:
                dump, self._dump = self._dump, None
                dump.close({"names": np.array(self._header.names), "fps": self._header.fps})

    def stats(self, seconds: float) -> dict:
        """Frames decoded, written, concealed and interpolated, decoder counters, latency in ms;
        for a sealed stream the packets opened and rejected."""
        s = self.source.decoder.stats if self.source is not None else None
        secure = getattr(self.source.decoder, "security", None) if self.source is not None else None
        ms = np.array(self.latency) * 1000 if self.latency else np.zeros(1)
        return {
            "frames": self.frames, "written": self.written, "concealed": self.concealed,
            "interpolated": self.interpolated, "picture_packets": self.layer_packets,
            "picture_lost": self.counts.layer_lost,
            "damage_reports": s.damaged if s else 0, "packets": s.packets if s else 0,
            "duplicates": s.duplicates if s else 0, "skipped_bytes": s.skipped_bytes if s else 0,
            "ended": bool(self.source and self.source.decoder.ended),
            "fps": self._header_seen.fps if self._header_seen else None,
            "output_fps": float(self._fps or self._header_seen.fps) if self._header_seen else None,
            "face": self.face_kind, "face_id": self.face_id, "look": self.look,
            "latency_ms": {"median": round(float(np.median(ms)), 2), "p95": round(float(np.percentile(ms, 95)), 2),
                           "max": round(1000 * self.latency_max, 2)},
            "frames_per_second": round(self.frames / max(seconds, 1e-9), 1),
            "security": secure.as_dict() if secure else None,
        }

    def summary(self, seconds: float) -> str:
        s = self.stats(seconds)
        lost = f", {s['picture_lost']} picture layer payloads lost" if s["picture_lost"] else ""
        return (f"{s['frames']} frames rendered ({s['concealed']} concealed, "
                f"{s['damage_reports']} damage reports{lost}), "
                f"{s['written']} written at {s['output_fps']:g} fps, {s['face']} face ({s['look']}), latency "
                f"{s['latency_ms']['median']:.1f} ms median, {s['latency_ms']['max']:.1f} ms max, "
                f"{s['frames_per_second']:.1f} frames/s" + _security_summary(s["security"]))


def decoded_dump(path: str, k: int) -> NpzAppender:
    """fd-recv --dump: per decoded frame its k parameters, number and flags; the layout and rate."""
    return NpzAppender(path, {"params": (np.float64, (k,)), "seq": (np.int64, ()), "face_seen": (np.bool_, ()),
                              "concealed": (np.bool_, ()), "interpolated": (np.bool_, ())})


def _security_summary(s: dict | None) -> str:
    if s is None:
        return ""
    return (f"; sealed: {s['opened']} packets authentic, {s['auth_failures']} failed authentication, "
            f"{s['replays']} replays dropped")
