"""One sending session: a source of frames -> packets, plus statistics and the research dump."""

import sys
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import replace
from itertools import chain, islice
from pathlib import Path

import numpy as np

from facedeform.codec.face_file.format import Face, preview_face
from facedeform.codec.model.face_model import load_base_face
from facedeform.codec.model.regions import DEFAULT_RULE
from facedeform.common.errors import InputError
from facedeform.common.limits import MAX_SIDE
from facedeform.common.npz import NpzAppender
from facedeform.common.parameters import BASIS_PARAMS, PLACING_PARAMS, POSE_PARAMS
from facedeform.common.stages import Source
from facedeform.protocol.basis import principal_basis
from facedeform.protocol.encoder import EAGER_GAP, EAGER_SECONDS
from facedeform.protocol.header import MAX_AHEAD
from facedeform.protocol.layouts import shipped_basis
from facedeform.protocol.rate import sample_bits_per_second
from facedeform.protocol.report import Report
from facedeform.protocol.secure import SecureSealer
from facedeform.protocol.stream import (
    DEFAULT_QUALITY,
    QUALITIES,
    Datagrams,
    Header,
    PacketEncoder,
    RateKeeper,
    frame_bytes,
    quality_for_bitrate,
    steps_for,
    stream_size,
)
from facedeform.sender.analysis import FaceAnalyser, FrameAnalysis, Smoothing, resolve_layout
from facedeform.sender.config import (
    DATAGRAM_FRAMES,
    LEVEL_SHARE,
    SPEAKER_RATE,
    STREAM_FRAMES,
    SendConfig,
    parameter_rate,
)
from facedeform.sender.face_pacing import FacePacing
from facedeform.sender.link import LEAN_KEYS, LinkWatch
from facedeform.sender.picture_layer import KEY_EVERY, LEAN_KEY_EVERY, WINDOW, PictureLayer, layer_pays
from facedeform.sender.pixel_pose import PixelPose, refines
from facedeform.sender.sources import open_source

#: Seconds between keyframes over datagrams: a burst that defeats the copies of each packet
#: freezes the face until the next keyframe. On four dev clips' streams (docs/bitstream.md, "Bursts"),
#: with three copies and a frame a datagram (sender.config.DATAGRAM_FRAMES), a keyframe every 6 frames
#: kept every concealed run within 10 frames in bursts of 8 datagrams and 12 in Gilbert-Elliott bursts
#: (a keyframe every 8: 12 and 14); against 2 frames a datagram and a keyframe every 10 (0.4 s; 18
#: and 14) it cost 22 % more bits.
DATAGRAM_KEYS = 0.24
#: Where --bitrate cannot carry the parameters over datagrams even without copies, a keyframe at every
#: 2nd, then 4th key place (about a second: a late joiner and a loss wait at most that long, as for the
#: picture layer's keys).
MOST_KEY_EVERY = 4


def key_seconds(header: Header) -> float:
    """Seconds between the keyframes of a stream with ``header``."""
    return header.key_interval * header.divisor / header.fps


def stream_header(names: tuple[str, ...], fps: float, face_id: str, quality: int = DEFAULT_QUALITY,
                  model_size: int = 0, basis: np.ndarray | None = None, divisor: int = 1,
                  size: tuple[int, int] = (0, 0), rule: str = DEFAULT_RULE, keys: float = 1.0,
                  preview_size: int = 0, ahead: float = 0.0) -> Header:
    """The header fd-send writes: a keyframe every ``keys`` seconds (of the frames sent: one in
    ``divisor``), and static-frame flags (with the dead zone a still face sends unchanged frames,
    a flag each); ``size``: the source's (width, height) in pixels; ``rule``: the deformation rule
    fitted to; ``preview_size``: the in-band model's first bytes that are a preview face; ``ahead``:
    seconds a frame may wait for the picture layer's next video frame."""
    return Header(fps, names, steps_for(names, quality), face_id, quality=quality,
                  key_interval=max(1, min(255, round(keys * fps / divisor))), divisor=divisor, skip_static=True,
                  model_size=model_size, basis=basis, width=size[0], height=size[1], rule=rule,
                  preview_size=preview_size, ahead=min(MAX_AHEAD, round(ahead * fps)))


def sample_basis(names: tuple[str, ...], sample: list[np.ndarray]) -> np.ndarray | None:
    """The coding basis of ``protocol.basis`` for a sample of the call's parameters, where the head,
    camera and body are (PLACING_PARAMS) apart; None for a layout with a motion basis's coefficients,
    which are decorrelated already (a coding basis on top saved 0-7 % on the dev clips' held-out halves
    and cost 0-5 % more on fd-experiment's 4 s clips, for 144-324 header bytes). Steps scale alike at
    every level, so the basis does not depend on the level."""
    if any(n in BASIS_PARAMS for n in names):
        return None
    return principal_basis(np.array(sample), steps_for(names), [n in PLACING_PARAMS for n in names])


def first_second(fps: float) -> int:
    """Frames in the call's first second: the sender holds them to find the rest face, and learns
    the coding basis and the --bitrate level from them before the header goes out."""
    return max(1, round(fps))


def first_frames(fps: float, results: list[FrameAnalysis]) -> list[tuple[np.ndarray, bool]]:
    """(parameters, face seen) of the call's first second: what --bitrate codes at every level,
    and what :func:`first_basis` learns from."""
    return [(r.params, r.landmarks is not None) for r in results[:first_second(fps)]]


def first_basis(names: tuple[str, ...], fps: float, frames: Sequence[tuple[np.ndarray, bool]]) -> np.ndarray | None:
    """The coding basis fd-send sends for a call that starts with ``frames`` ((parameters, face
    seen), as :func:`first_frames` gives them or a dump holds them): the one every package holds
    for the layout (``protocol.layouts``: as good on speakers it was not trained on, and one byte
    in the header), else from its first second's frames with a face."""
    held = shipped_basis(names)
    return held if held is not None else sample_basis(
        names, [params for params, seen in frames[:first_second(fps)] if seen])


def read_dump(path, layout: tuple[str, ...] | None = None) -> tuple[tuple[str, ...], float, np.ndarray, np.ndarray]:
    """(parameter names, fps, (n, k) unquantised parameters, (n,) face seen) of a file that
    :meth:`SendSession.dump` wrote; with ``layout``, the parameters of those names only, in its order."""
    with np.load(path) as d:
        names, fps, params, found = tuple(str(n) for n in d["names"]), float(d["fps"]), d["params"], d["found"]
    if layout is None:
        return names, fps, params, found
    return tuple(layout), fps, params[:, [names.index(n) for n in layout]], found


def dump_writer(path: str | Path, k: int) -> NpzAppender:
    """The research dump, written as frames pass (``FrameAnalysis`` rows by :func:`dump_row`):
    per frame landmarks (pixels), pose-free targets (base-face units), face seen, head pose (NaN
    without a face) and the k unquantised parameters; :func:`read_dump` reads it."""
    return NpzAppender(path, {"landmarks": (np.float32, (468, 3)), "targets": (np.float32, (468, 3)),
                              "found": (np.bool_, ()), "pose_rotation": (np.float64, (3, 3)),
                              "pose_translation": (np.float64, (3,)), "pose_scale": (np.float64, ()),
                              "params": (np.float64, (k,))})


def dump_row(f: FrameAnalysis) -> dict:
    """One frame's row of :func:`dump_writer`."""
    row: dict[str, object] = {"found": f.landmarks is not None, "params": f.params}
    if f.landmarks is not None and f.pose is not None:  # else NaN
        row.update(landmarks=f.landmarks, targets=f.target, pose_rotation=f.pose.rotation,
                   pose_translation=f.pose.translation, pose_scale=f.pose.scale)
    return row


def _copies_going(copies: int) -> str:
    """What ``copies`` copies of each packet against loss mean, said to the user."""
    if copies < 2:
        return ("none go: a lost datagram costs frames until the next keyframe",
                "one goes: a datagram lost alone costs no frame")[copies]
    return f"{copies} go: up to {copies} datagrams lost in a row cost no frame"


class SendSession:
    """Opens the source and the models; :meth:`packets` yields the packets as frames are analysed.

    source: a path (video file, image directory or %d pattern) or an opened
    source (``sender.sources``); config: how the call is coded (:class:`sender.config.SendConfig`);
    face: the person's face model (fd-enroll) to fit and render instead of the generic face,
    carried in the stream when ``config.embed_face``;
    dump: a .npz path to write the research dump to (:func:`dump_writer`), finished by :meth:`close`;
    warn: called with a line where the call cannot be coded as asked (default: printed on stderr).
    Over datagrams without a key, :attr:`feedback` (set it to the sink's ``report``) gives the
    receiver's loss reports, by which the copies are sent only while datagrams are lost (sender/link.py).
    Memory does not grow with the call: only counters are kept of the frames sent.
    """

    def __init__(self, source: str | Source, config: SendConfig | None = None, dump: str | Path | None = None,
                 face: Face | None = None, warn: Callable[[str], None] | None = None) -> None:
        from facedeform.sender.tracker import FaceTracker

        self.config = config = config or SendConfig()
        self._warn = warn or (lambda line: print(f"fd-send: warning: {line}", file=sys.stderr))
        self.source = open_source(source) if isinstance(source, str) else source
        if max(self.source.size) > MAX_SIDE:
            raise InputError(f"the source is {self.source.size[0]}x{self.source.size[1]} pixels: a stream carries "
                             f"at most {MAX_SIDE} a side (scale it down first)")
        model = load_base_face() if face is None else face.model
        fps = self.source.fps
        self.analyser = FaceAnalyser(FaceTracker(), model, fps, config.layout, calibration_frames=round(fps),
                                     neutral=config.neutral, smoothing=Smoothing(config.smoothing), rule=config.rule)
        self._face_id = model.content_id
        self._face = model
        self._model = face.data if face is not None and config.embed_face else b""
        if config.paced_face and not self._model:
            raise InputError("a paced face needs the face model (--face FILE)")
        #: a paced face's preview goes before the face itself (sender/face_pacing.py)
        self._preview = preview_face(model) if config.paced_face else b""
        self._model = self._preview + self._model
        self._pacing: FacePacing | None = None
        #: the picture layer where the call sends one (``_layer_rate``), once the header is
        self.picture: PictureLayer | None = None
        self._layer_counts: tuple[int, int] | None = None  # packets and bits of the layers stopped; None: none ran
        #: over datagrams, the layer pays only without the copies: it runs while the link is lean (_check_room)
        self._lean_layer = False
        #: over datagrams, bit/s the parameters take with their copies and the header's repeats, and lean
        #: (_check_room): where the layer plans from at its start
        self._parameter_costs = (0.0, 0.0)
        self._basis: np.ndarray | None = None
        self.sealer = None if config.key is None else SecureSealer(config.key, config.tag_bits)
        reference = model.picture
        #: The call's whole rate where it sends a picture layer, else None: a --bitrate at which one pays
        #: (sender.picture_layer.layer_pays), a face with a reference picture, every frame sent.
        self._layer_rate = config.bitrate if (
            config.bitrate is not None and config.picture_layer and reference is not None and config.divisor == 1
            and layer_pays(config.bitrate, reference.image.shape[1::-1])) else None
        self._aim, self._finest, self._level_share = self._parameter_aim(resolve_layout(config.layout, model))
        self._keeper: RateKeeper | None = None
        #: The head's pose over a reference picture is coded by plain rounding at the call's dead zone (held
        #: only as the rate keeper widens it): fitted there in pixels to a fraction of a step
        #: (sender/pixel_pose.py), held within a step it drew the head that far off. On the nine dev crops
        #: at fd-send's defaults +0.013 to +0.058 dB (+0.038 on average) for 4 % more rate, several times
        #: what a finer level buys with as much (docs/bitstream.md).
        self._rounded = POSE_PARAMS if refines(model, self.analyser.names) else ()
        #: copies of each frames packet over datagrams: --redundancy, fewer where --bitrate cannot carry them
        self._copies = config.redundancy
        #: over datagrams, a keyframe at every so many key places at least: more than one where --bitrate
        #: cannot carry one at each even without copies (_check_room)
        self._key_every = 1
        self._configure(DEFAULT_QUALITY if config.level is None else config.level)
        # once: a later _configure changes the level, not the layout, rule or face the view draws
        self._pixel_pose = PixelPose(model, self.header) if refines(model, self.header.names) else None
        self.frame_count = 0
        self._dump_path = dump
        self._dump: NpzAppender | None = None
        self.stream_bytes = 0  # as a byte stream (sync bytes included), header excluded
        self.header_bytes = 0
        self._ended = False
        self._started = time.perf_counter()
        #: the newest loss report since the last call (None: none came), where the sink reads them
        self.feedback: Callable[[], Report | None] | None = None
        #: what the receiver's reports say of the link; a simulated call gives it the call's own clock
        self.link = LinkWatch()
        self.lean_frames = 0  # frames sent lean: without copies, on a link that lost nothing
        #: bits of the last frames sent, WINDOW seconds less a frame: what a paced face and the picture layer keep
        #: the stream within (the layer from the window as the frames before it spent it)
        self._recent: deque[int] = deque(maxlen=max(1, round(WINDOW * self.source.fps)) - 1)
        #: bits of the window ending at the last frame sent, and of the costliest window so far: what a
        #: user checks --bitrate against (the end mark and the last packet it holds count with the last frame)
        self._window = self._costliest = 0

    @property
    def sealed(self) -> bool:
        """Packets are sealed (opaque): on a byte stream each needs its sync byte."""
        return self.sealer is not None

    def _parameter_aim(self, layout: str) -> tuple[float | None, int, float]:
        """(bit/s the parameters aim at, None for a fixed level; the finest level to take; the share of
        the aim the level's sample must fit): their share of --bitrate where a picture layer runs or a
        paced face comes (for the whole call: the level is the header's), all of it where neither does
        (the level chosen within LEVEL_SHARE of it), or by default with the speaker's own motion basis
        SPEAKER_RATE, the same way: a finer level where it fits took lipnet_bbaf2n's mouth swing from
        0.83 to 0.86 of the speaker's (level 4 at 1.32 kbit/s; README, expression table)."""
        bitrate = self.config.bitrate
        if bitrate is not None:
            if self._layer_rate is not None or self.config.paced_face:
                return parameter_rate(bitrate), max(QUALITIES), 1.0
            return bitrate, max(QUALITIES), LEVEL_SHARE
        default = self.config.level is None and layout == "personal"
        return (SPEAKER_RATE, max(QUALITIES), LEVEL_SHARE) if default else (None, DEFAULT_QUALITY, 1.0)

    def _header(self, quality: int) -> Header:
        return stream_header(self.analyser.names, self.source.fps, self._face_id, quality, len(self._model),
                             self._basis, self.config.divisor, self.source.size, self.config.rule,
                             DATAGRAM_KEYS if self.config.datagrams else 1.0, len(self._preview),
                             0.0 if self._layer_rate is None else self.config.ahead)

    def _configure(self, quality: int) -> None:
        self.header = self._header(quality)
        self.encoder = PacketEncoder(self.header, self.config.packet_frames, self._model, self.config.dead_zone,
                                     self._rounded)
        keys = key_seconds(self.header)
        self.datagrams = Datagrams(self.encoder.header()[0], self._copies,
                                   eager=round(EAGER_SECONDS / keys), sealer=self.sealer,
                                   eager_every=round(EAGER_GAP / keys),
                                   key_interval=self.header.key_interval) if self.config.datagrams else None

    def packets(self) -> Iterator[list[bytes]]:
        """Lists of packets: the header once a face is known (a clip without one sends nothing),
        then what each frame completes, then the end mark."""
        results = self.analyser.run(self.source.frames())
        aim = self._aim
        if aim is not None or self.config.basis:  # the analyser holds the first second anyway
            fps = self.source.fps
            first = list(islice(results, first_second(fps)))
            sample = first_frames(fps, first)
            if self.config.basis:
                self._basis = first_basis(self.analyser.names, fps, sample)
            quality = self.header.quality
            if first and aim is not None:
                # where the parameters keep the whole --bitrate, the level moves as the call grows livelier
                # than its first second, or quieter (protocol/rate.py)
                moves = self._layer_rate is None and not self.config.paced_face and self.config.bitrate is not None
                start = aim
                if self.datagrams is not None:  # the header's repeats for late joiners come out of it too
                    self._configure(quality)  # the header as it goes, its basis now known: what they cost
                    keys = key_seconds(self.header)
                    aim = max(0.0, aim - self.datagrams.repeat_rate(keys))
                    # and where they keep the whole rate, its first, eager repeats from the first seconds'
                    start = max(0.0, aim - self.datagrams.eager_rate(keys)) if moves else aim
                quality = quality_for_bitrate(self._header, sample, self._level_share * start,
                                              self.config.packet_frames, self.config.dead_zone,
                                              0 if self.sealer is None else self.sealer.overhead,
                                              self.config.redundancy if self.config.datagrams else None, self._finest,
                                              self._rounded)
                self._keeper = RateKeeper(aim, fps, self.config.dead_zone, quality if moves else None, self._finest)
            self._configure(quality)
            if first and aim is not None:
                # on the header as it goes: the one configured before had cost the repeats of one 5 times
                # its size (the bundled clip's first 4 s over udp:// at 2.6 kbit/s where they take 0.5)
                self._check_room(quality, sample)
            if self._layer_rate is not None and not self._preview:
                self._start_layer()
            results = chain(first, results)
        if self._preview and self.config.bitrate is not None:  # (a preview is only made with a bitrate)
            self._pacing = FacePacing(self.encoder, len(self._model), self.config.bitrate, self.source.fps,
                                      self.sealed, rounds=self.config.datagrams, preview=len(self._preview))
        for seq, result in enumerate(results):
            if seq == 0:
                header = self._seal(self.encoder.header(model=self._pacing is None))
                if self.sealer is not None:
                    header.insert(0, self.sealer.preamble())
                self.header_bytes = stream_size(header, self.sealed)
                yield header
            self.frame_count += 1
            if self._pixel_pose is not None and result.landmarks is not None and result.frame is not None:
                result = replace(result, params=self._pixel_pose.refine(result.params, result.frame, result.landmarks))
            if self._dump_path is not None:
                if self._dump is None:
                    self._dump = dump_writer(self._dump_path, len(self.header.names))
                self._dump.add(**dump_row(result))
            report = self._follow_link()
            if self._pacing is not None:
                self._pacing.hear(report)
                if not self._pacing.done and self.picture is not None:  # a receiver that lacks the face joined
                    self._stop_layer()
            if self._lean_layer and self.picture is not None and not self.link.lean:
                self._stop_layer()  # the copies are back, and leave the layer too little
            elif self._lean_layer and self.picture is None and self._pacing is None:
                self._start_layer()
            repeats_before = (0, 0) if self.datagrams is None else (self.datagrams.repeated,
                                                                     self.datagrams.eager_repeated)
            packets = self._seal(self.encoder.frame(result.params, result.landmarks is not None))
            repeats = eager = 0
            if self.datagrams is not None:
                repeats = 8 * (self.datagrams.repeated - repeats_before[0])
                eager = 8 * (self.datagrams.eager_repeated - repeats_before[1])
            if self._keeper is not None:  # on the frames' bits: the later repeats' share was taken off its aim
                self.encoder.dead_zone = self._keeper.step(8 * stream_size(packets, self.sealed) - repeats, eager)
                level = self._keeper.level
                if level is not None and level != self.encoder.level:  # over datagrams at a key place
                    self.encoder.relevel(level, at_place=self.datagrams is not None)
                if self._keeper.short and self.datagrams is not None:
                    self._shed(seq)
            drawn_from = self.encoder.reconstruction  # what the receiver decodes of this frame
            if self.picture is not None and result.frame is not None and drawn_from is not None:
                packets = self._seal(self.picture.step(seq, result.frame, drawn_from, self.encoder, packets,
                                                       repeats)) + packets
            if self._pacing is not None:
                packets = self._seal(self._pacing.step(8 * stream_size(packets, self.sealed), sum(self._recent))) \
                    + packets
            size = stream_size(packets, self.sealed)
            self.stream_bytes += size
            bits = 8 * size
            self._window = sum(self._recent) + bits
            self._costliest = max(self._costliest, self._window)
            self._recent.append(bits)
            if self._pacing is not None and self._pacing.drained and self.picture is None:
                self._start_layer()  # the receiver holds the face: the layer from the next frame
                if not self.config.datagrams:  # (over datagrams a receiver may join that lacks it)
                    self._pacing = None
            if packets:
                yield packets
        yield self.end()

    def _start_layer(self) -> None:
        """The picture layer from the next frame on, where the call sends one and the link allows it
        (its window as the frames before it spent it)."""
        if self._layer_rate is not None and (self.link.lean or not self._lean_layer):
            self._layer_counts = self._layer_counts or (0, 0)
            self.picture = PictureLayer(self._face, self.header, self._layer_rate, self._recent, self.sealed,
                                        self.config.datagrams, self._parameter_costs[self.link.lean],
                                        None if self.datagrams is None else self._repeats_ahead)

    def _repeats_ahead(self, seq: int, count: int) -> np.ndarray:
        """Bits of the header's repeats over datagrams that go with each of the ``count`` frames after
        frame ``seq``, as the parameters' keyframes fall and the repeats' schedule now stands."""
        h, every, datagrams = self.header, self.encoder.key_every, self.datagrams
        bits = np.zeros(count)
        if datagrams is None:
            return bits
        place = h.key_interval * h.divisor  # frames a key place spans
        span = place * every  # frames between keyframes
        frames = range(-(-(seq + 1) // span) * span, seq + 1 + count, span)
        repeats = datagrams.repeats_ahead(f // place for f in frames)
        bits[[f - seq - 1 for f, r in zip(frames, repeats) if r]] = 8 * datagrams.repeat_size
        return bits

    def _stop_layer(self) -> None:
        """No picture layer from this frame on (its packets and bits stay counted)."""
        if self.picture is not None:
            self.picture.close()
            self._layer_counts = self._layer_totals()
            self.picture = None

    def _layer_totals(self) -> tuple[int, int] | None:
        """(packets, bits) of the picture layer in the call so far; None where none ran."""
        if self._layer_counts is None:
            return None
        packets, bits = self._layer_counts
        return (packets, bits) if self.picture is None else (packets + self.picture.packets, bits + self.picture.bits)

    def _follow_link(self) -> Report | None:
        """Over datagrams, with the receiver's reports and no key: the copies, a frame a datagram and a
        keyframe at every key place while it loses datagrams or may; none, STREAM_FRAMES (or the frames
        a packet asked) and a keyframe every LEAN_KEYS places while it does not. The report heard, if any."""
        if self.feedback is None or self.datagrams is None or self.sealer is not None:
            return None
        report = self.feedback()
        self.link.hear(report)
        lean = self.link.lean
        self.datagrams.copies = 0 if lean else self._copies
        self.encoder.frames_per_packet = self.config.frames_per_packet or (STREAM_FRAMES if lean else DATAGRAM_FRAMES)
        self.encoder.key_every = max(self._key_every, LEAN_KEYS if lean else 1)
        self.datagrams.joined, self.datagrams.lean = self.link.heard, lean
        if self.picture is not None:
            self.picture.key_every = LEAN_KEY_EVERY if lean else KEY_EVERY
            if report is not None and self.link.lost:
                self.picture.key_soon()
        self.lean_frames += lean
        return report

    def _shed(self, seq: int) -> None:
        """From frame ``seq`` on, the call costing more than --bitrate at the coarsest level
        (protocol/rate.py): one copy of each packet fewer (the copies were chosen from its first second),
        or without copies a keyframe at half as many key places, down to MOST_KEY_EVERY."""
        assert self.datagrams is not None
        if self._copies > 0:
            self._copies -= 1
            self.datagrams.copies = min(self.datagrams.copies, self._copies)
            level, going = "level", _copies_going(self._copies)
        elif self._key_every < MOST_KEY_EVERY:
            self._key_every *= 2
            self.encoder.key_every = max(self.encoder.key_every, self._key_every)
            level, going = "level without copies", self._keys_going()
        else:
            return
        bitrate = self.config.bitrate or 0.0
        self._warn(f"from frame {seq} the call costs more than the {bitrate / 1000:g} kbit/s asked at the coarsest "
                   f"{level}; {going}")

    def _keys_going(self) -> str:
        """How often keyframes go, said to the user where fewer go than the header's places."""
        keys = key_seconds(self.header)
        return (f"a keyframe goes every {self._key_every * keys:.2g} s instead of every {keys:.2g} s: a lost "
                f"datagram costs the frames up to the next one, and a late joiner waits for it")

    def _check_room(self, quality: int, sample: Sequence[tuple[np.ndarray, bool]]) -> None:
        """Over datagrams, where the parameters as they go (their first second ``sample`` at ``quality``,
        with their copies and keyframes and the header's repeats) leave the picture layer too little to
        pay, it runs only while the link is lean (no copies: the receiver reports no loss) where that
        leaves it enough, else it is not sent (on a byte stream they keep within their share). Where
        they take more than --bitrate with their copies, fewer copies go, down to none; where they then
        take more than LEVEL_SHARE of it at the coarsest level (the call grows livelier than its first
        second), a keyframe at fewer key places (up to MOST_KEY_EVERY); where they still take more than
        it, says so."""
        bitrate, datagrams = self.config.bitrate, self.datagrams
        if bitrate is None:
            return
        header = self._header(quality)

        keys = key_seconds(header)
        repeats = 0.0 if datagrams is None else datagrams.repeat_rate(keys) + datagrams.eager_rate(keys)

        def cost_with(copies: int | None, key_every: int = 1) -> float:
            return repeats + sample_bits_per_second(header, sample, self.config.packet_frames, self.config.dead_zone,
                                                    0 if self.sealer is None else self.sealer.overhead, copies,
                                                    key_every, self._rounded)

        cost, over = cost_with(None if datagrams is None else self._copies), ""
        if datagrams is not None:
            over = " with the copies, keyframes and header repeats of udp://"
            copies, every = self._copies, 1
            while cost > bitrate and copies > 0:  # --bitrate is the whole budget, the copies' too
                copies -= 1
                cost = cost_with(copies)
            full = cost  # then, at the coarsest level, fewer keyframes, with the room a level keeps
            while (cost > self._level_share * bitrate and copies == 0 and quality == min(QUALITIES)
                   and every < MOST_KEY_EVERY):
                every *= 2
                cost = cost_with(0, every)
            going = []
            if copies < self._copies:
                going.append(f"with {self._copies} copies of each packet against loss the parameters would take "
                            f"more than the {bitrate / 1000:g} kbit/s asked; {_copies_going(copies)}")
                self._copies = datagrams.copies = copies
            if every > 1:
                self._key_every = self.encoder.key_every = every
                going.append(f"without copies the parameters would take about {full / 1000:.1f} kbit/s, so "
                            f"{self._keys_going()}")
            if going:
                self._warn("; ".join(going) + f" (about {cost / 1000:.1f} kbit/s)")
            lean = sample_bits_per_second(header, sample, STREAM_FRAMES, self.config.dead_zone, 0, 0,
                                          rounded=self._rounded) + \
                datagrams.repeat_rate(keys)
            self._parameter_costs = (cost, lean)
        reference = self._face.picture
        if self._layer_rate is not None and reference is not None and datagrams is not None and \
                not layer_pays(bitrate, reference.image.shape[1::-1], cost):
            said = f"the parameters take about {cost / 1000:.1f} of the {bitrate / 1000:g} kbit/s asked{over}: "
            if self.sealer is None and layer_pays(bitrate, reference.image.shape[1::-1], lean):
                self._lean_layer = True
                self._warn(said + f"the picture layer waits until fd-recv reports a link that loses nothing "
                                  f"(about {lean / 1000:.1f} then)")
            else:
                self._layer_rate = None
                self._warn(said + "too little is left for the picture layer, which is not sent")
        if cost > bitrate:
            level = "at their coarsest" if quality == min(QUALITIES) else f"at level {quality}"
            self._warn(f"the parameters take about {cost / 1000:.1f} kbit/s {level}{over}, more than "
                       f"the {bitrate / 1000:g} asked: the stream will go over it")

    def end(self) -> list[bytes]:
        """The end mark (and the last pending packet), once; [] if already sent or nothing was."""
        if self._ended or not self.frame_count:
            return []
        self._ended = True
        if self.picture is not None:
            self.picture.close()
        packets = self._seal(self.encoder.end())
        size = stream_size(packets, self.sealed)
        self.stream_bytes += size
        self._costliest = max(self._costliest, self._window + 8 * size)
        return packets

    def _seal(self, packets: list[bytes]) -> list[bytes]:
        if self.datagrams is not None:
            return self.datagrams.add(packets)
        return packets if self.sealer is None else self.sealer.seal_all(packets)

    def stream(self) -> Iterator[bytes]:
        """The same as a byte stream."""
        for packets in self.packets():
            if packets:
                yield frame_bytes(packets, self.sealed)

    def stats(self) -> dict:
        """Frames, frames without a face, bits per frame, bit rate and that of the costliest 2 seconds (the
        window --bitrate is kept over), processing speed, rest frame."""
        n = self.frame_count
        bits = 8 * self.stream_bytes / max(n, 1)
        rest = self.analyser.rest
        layer = self._layer_totals()
        window = ((self._recent.maxlen or 0) + 1) / self.source.fps  # seconds
        return {"frames": n, "frames_without_face": self.analyser.frames_without_face,
                "quality": self.header.quality,
                "bits_per_frame": round(bits, 1), "kbit_per_s": round(bits * self.source.fps / 1000, 3),
                "fps": self.source.fps, "header_bytes": self.header_bytes, "layout": list(self.header.names),
                "basis": self.header.basis is not None, "send_every": self.header.divisor,
                "rest_frame": None if rest is None else rest.index,
                "tag_bits": None if self.sealer is None else 8 * self.sealer.tag_bytes,
                "lean_frames": self.lean_frames, "level_changes": self.encoder.level_changes,
                "picture_packets": None if layer is None else layer[0],
                "picture_bits_per_frame": None if layer is None else round(layer[1] / max(n, 1), 1),
                "costliest_2s_kbit_per_s": round(self._costliest / window / 1000, 3),
                "frames_per_second": round(n / max(time.perf_counter() - self._started, 1e-9), 1)}

    def summary(self) -> str:
        s = self.stats()
        layer = "" if s["picture_packets"] is None else \
            f" ({s['picture_bits_per_frame'] * s['fps'] / 1000:.2f} of them the picture layer's)"
        return (f"{s['frames']} frames ({s['frames_without_face']} without a face), "
                f"{s['bits_per_frame']:.0f} bits/frame, {s['kbit_per_s']:.2f} kbit/s{layer} at {s['fps']:g} fps "
                f"(+{s['header_bytes']} header bytes; at most {s['costliest_2s_kbit_per_s']:.2f} kbit/s over any 2 s), "
                f"rest face: frame {s['rest_frame']}, "
                f"{s['frames_per_second']:.1f} frames/s")

    def close(self) -> None:
        """Ends the picture layer's encoder (the stream may have been left before its end) and finishes
        the dump, if one was asked for and a frame was sent (else no file is written)."""
        if self.picture is not None:
            self.picture.close()
        if self._dump is not None:
            dump, self._dump = self._dump, None
            dump.close({"names": np.array(self.header.names),
                        "rest_frame": -1 if self.analyser.rest is None else self.analyser.rest.index,
                        "fps": self.source.fps, "width": self.source.size[0], "height": self.source.size[1]})
