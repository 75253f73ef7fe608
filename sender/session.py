"""One sending session: a source of frames -> packets, plus statistics and the research dump."""

import time
from collections.abc import Iterator, Sequence
from itertools import chain, islice

import numpy as np

from codec.deform import POSE_PARAMS
from codec.face_file import decode_face, read_face_bytes
from codec.face_model import load_base_face
from codec.motion_basis import BASIS_PARAMS
from protocol.basis import principal_basis
from protocol.secure import SecureSealer
from protocol.stream import DEFAULT_QUALITY, Header, PacketEncoder, frame_bytes, quality_for_bitrate, steps_for
from sender.analysis import FaceAnalyser, FrameAnalysis, Smoothing
from sender.config import SendConfig
from sender.sources import open_source


def stream_header(names: tuple[str, ...], fps: float, face_id: str, quality: int = DEFAULT_QUALITY,
                  model_size: int = 0, basis: np.ndarray | None = None, divisor: int = 1,
                  sealed: bool = False, size: tuple[int, int] = (0, 0)) -> Header:
    """The header fd-send writes: a keyframe a second (of the frames sent: one in ``divisor``), and
    static-frame flags (with the dead zone a still face sends unchanged frames, a flag each);
    version 6, or 5 for a ``sealed`` stream (whose byte stream reads packet lengths); ``size``: the
    source's (width, height) in pixels."""
    return Header(fps, names, steps_for(names, quality), face_id, quality=quality,
                  key_interval=max(1, min(255, round(fps / divisor))), divisor=divisor, skip_static=True,
                  model_size=model_size, basis=basis, self_delimiting=not sealed, width=size[0], height=size[1])


def sample_basis(names: tuple[str, ...], sample: list[np.ndarray]) -> np.ndarray | None:
    """The coding basis of ``protocol.basis`` for a sample of the call's parameters, head pose apart;
    None for a layout with a motion basis's coefficients, which are decorrelated already (a coding
    basis on top saved 0-7 % on the dev clips' held-out halves and cost 0-5 % more on fd-experiment's
    4 s clips, for 144-324 header bytes). Steps scale alike at every level, so the basis does not
    depend on the level."""
    if any(n in BASIS_PARAMS for n in names):
        return None
    return principal_basis(np.array(sample), steps_for(names), [n in POSE_PARAMS for n in names])


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
    seen), as :func:`first_frames` gives them or a dump holds them): from its first second's frames
    with a face."""
    return sample_basis(names, [params for params, seen in frames[:first_second(fps)] if seen])


def read_dump(path, layout: tuple[str, ...] | None = None) -> tuple[tuple[str, ...], float, np.ndarray, np.ndarray]:
    """(parameter names, fps, (n, k) unquantised parameters, (n,) face seen) of a file that
    :meth:`SendSession.dump` wrote; with ``layout``, the parameters of those names only, in its order."""
    with np.load(path) as d:
        names, fps, params, found = tuple(str(n) for n in d["names"]), float(d["fps"]), d["params"], d["found"]
    if layout is None:
        return names, fps, params, found
    return tuple(layout), fps, params[:, [names.index(n) for n in layout]], found


class SendSession:
    """Opens the source and the models; :meth:`packets` yields the packets as frames are analysed.

    source: a path (video file, image directory or %d pattern) or an opened
    source (``sender.sources``); config: how the call is coded (:class:`sender.config.SendConfig`).
    """

    def __init__(self, source, config: SendConfig | None = None) -> None:
        from sender.tracker import FaceTracker

        self.config = config = config or SendConfig()
        self.source = open_source(source) if isinstance(source, str) else source
        model = b""
        if config.face_file is None:
            face = load_base_face()
        else:
            data = read_face_bytes(config.face_file, config.key)  # a sealed file opens with the stream's key
            face = decode_face(data, config.face_file)
            model = data if config.embed_face else b""
        fps = self.source.fps
        self.analyser = FaceAnalyser(FaceTracker(), face, fps, config.layout, calibration_frames=round(fps),
                                     neutral=config.neutral, smoothing=Smoothing(config.smoothing))
        self._face_id, self._model, self._basis = face.content_id, model, None
        self.sealer = None if config.key is None else SecureSealer(config.key, config.tag_bits)
        self._configure(config.quality)
        self.frames: list[FrameAnalysis] = []
        self.stream_bytes = 0  # as a byte stream (sync bytes included), header excluded
        self.header_bytes = 0
        self._ended = False
        self._started = time.perf_counter()

    @property
    def sealed(self) -> bool:
        """Packets are sealed (opaque): on a byte stream each needs its sync byte."""
        return self.sealer is not None

    def _header(self, quality: int) -> Header:
        return stream_header(self.analyser.names, self.source.fps, self._face_id, quality, len(self._model),
                             self._basis, self.config.divisor, self.sealed, self.source.size)

    def _configure(self, quality: int) -> None:
        self.header = self._header(quality)
        self.encoder = PacketEncoder(self.header, self.config.frames_per_packet, self._model, self.config.dead_zone)

    def packets(self) -> Iterator[list[bytes]]:
        """Lists of packets: the header once a face is known (a clip without one sends nothing),
        then what each frame completes, then the end mark."""
        results = self.analyser.run(self.source.frames())
        bitrate = self.config.bitrate
        if bitrate is not None or self.config.basis:  # the analyser holds the first second anyway
            fps = self.source.fps
            first = list(islice(results, first_second(fps)))
            sample = first_frames(fps, first)
            if self.config.basis:
                self._basis = first_basis(self.analyser.names, fps, sample)
            quality = self.header.quality
            if first and bitrate is not None:
                quality = quality_for_bitrate(self._header, sample, bitrate, self.config.frames_per_packet,
                                              self.config.dead_zone, 0 if self.sealer is None else self.sealer.overhead)
            self._configure(quality)
            results = chain(first, results)
        for seq, result in enumerate(results):
            if seq == 0:
                header = self._seal(self.encoder.header())
                if self.sealer is not None:
                    header.insert(0, self.sealer.preamble())
                self.header_bytes = len(frame_bytes(header, self.sealed))
                yield header
            self.frames.append(result)
            packets = self._seal(self.encoder.frame(result.params, result.landmarks is not None))
            self.stream_bytes += len(frame_bytes(packets, self.sealed))
            if packets:
                yield packets
        yield self.end()

    def end(self) -> list[bytes]:
        """The end mark (and the last pending packet), once; [] if already sent or nothing was."""
        if self._ended or not self.frames:
            return []
        self._ended = True
        packets = self._seal(self.encoder.end())
        self.stream_bytes += len(frame_bytes(packets, self.sealed))
        return packets

    def _seal(self, packets: list[bytes]) -> list[bytes]:
        return packets if self.sealer is None else self.sealer.seal_all(packets)

    def stream(self) -> Iterator[bytes]:
        """The same as a byte stream."""
        for packets in self.packets():
            if packets:
                yield frame_bytes(packets, self.sealed)

    def stats(self) -> dict:
        """Frames, frames without a face, bits per frame, bit rate, processing speed, rest frame."""
        n = len(self.frames)
        bits = 8 * self.stream_bytes / max(n, 1)
        rest = self.analyser.rest
        return {"frames": n, "frames_without_face": self.analyser.frames_without_face,
                "quality": self.header.quality,
                "bits_per_frame": round(bits, 1), "kbit_per_s": round(bits * self.source.fps / 1000, 3),
                "fps": self.source.fps, "header_bytes": self.header_bytes, "layout": list(self.header.names),
                "basis": self.header.basis is not None, "send_every": self.header.divisor,
                "rest_frame": None if rest is None else rest.index,
                "tag_bits": None if self.sealer is None else 8 * self.sealer.tag_bytes,
                "frames_per_second": round(n / max(time.perf_counter() - self._started, 1e-9), 1)}

    def summary(self) -> str:
        s = self.stats()
        return (f"{s['frames']} frames ({s['frames_without_face']} without a face), "
                f"{s['bits_per_frame']:.0f} bits/frame, {s['kbit_per_s']:.2f} kbit/s at {s['fps']:g} fps "
                f"(+{s['header_bytes']} header bytes), rest face: frame {s['rest_frame']}, "
                f"{s['frames_per_second']:.1f} frames/s")

    def write_dump(self, path: str) -> None:
        """Per frame: landmarks (pixels), pose-free targets (base-face units), head pose (NaN without
        a face) and unquantised parameters; and the rest frame's index."""
        n = len(self.frames)
        landmarks = np.full((n, 468, 3), np.nan, dtype=np.float32)
        targets = np.full((n, 468, 3), np.nan, dtype=np.float32)
        rotation = np.full((n, 3, 3), np.nan)
        translation = np.full((n, 3), np.nan)
        scale = np.full(n, np.nan)
        for i, f in enumerate(self.frames):
            if f.landmarks is not None:
                landmarks[i], targets[i] = f.landmarks, f.target
                rotation[i], translation[i], scale[i] = f.pose.rotation, f.pose.translation, f.pose.scale
        np.savez_compressed(
            path, landmarks=landmarks, targets=targets, found=np.array([f.landmarks is not None for f in self.frames]),
            pose_rotation=rotation, pose_translation=translation, pose_scale=scale,
            params=np.array([f.params for f in self.frames]), names=np.array(self.header.names),
            rest_frame=-1 if self.analyser.rest is None else self.analyser.rest.index,
            fps=self.source.fps, width=self.source.size[0], height=self.source.size[1])
