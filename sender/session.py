"""One sending session: video file -> stream bytes, plus statistics and the research dump."""

from collections.abc import Iterator

import numpy as np

from codec.deform import Deformer
from codec.face_model import load_base_face
from protocol.stream import DEFAULT_QUALITY, Header, StreamEncoder, steps_for
from sender.analysis import FaceAnalyser, FrameAnalysis
from sender.estimate import ParameterEstimator
from sender.video import VideoSource


class SendSession:
    """Opens the video and the models; :meth:`stream` yields the stream's bytes as frames are analysed."""

    def __init__(self, video_path: str, quality: int = DEFAULT_QUALITY, frames_per_packet: int = 2) -> None:
        from sender.tracker import FaceTracker

        self.video = VideoSource(video_path)
        face = load_base_face()
        estimator = ParameterEstimator(face, Deformer(face))
        self.analyser = FaceAnalyser(FaceTracker(), estimator, face.vertices,
                                     calibration_frames=round(self.video.fps))
        names = self.analyser.names
        self.header = Header(self.video.fps, names, steps_for(names, quality), face.content_id,
                             quality=quality, key_interval=max(1, min(255, round(self.video.fps))))
        self.encoder = StreamEncoder(self.header, frames_per_packet)
        self.frames: list[FrameAnalysis] = []
        self.stream_bytes = 0
        self.header_bytes = 0

    def stream(self) -> Iterator[bytes]:
        for seq, result in enumerate(self.analyser.run(self.video.frames())):
            if seq == 0:  # only once a face is known: a clip without one writes nothing
                header = self.encoder.header()
                self.header_bytes = len(header)
                yield header
            self.frames.append(result)
            packet = self.encoder.frame(result.params, result.landmarks is not None)
            self.stream_bytes += len(packet)
            if packet:
                yield packet
        end = self.encoder.end()
        self.stream_bytes += len(end)
        yield end

    def summary(self, seconds: float) -> str:
        n = len(self.frames)
        bits = 8 * self.stream_bytes / max(n, 1)
        return (f"{n} frames ({self.analyser.frames_without_face} without a face), "
                f"{bits:.0f} bits/frame, {bits * self.video.fps / 1000:.2f} kbit/s at {self.video.fps:g} fps "
                f"(+{self.header_bytes} header bytes), {n / max(seconds, 1e-9):.1f} frames/s")

    def write_dump(self, path: str) -> None:
        """Per frame: landmarks (NaN without a face), head pose and unquantised parameters."""
        n = len(self.frames)
        landmarks = np.full((n, 468, 3), np.nan, dtype=np.float32)
        rotation = np.full((n, 3, 3), np.nan)
        translation = np.full((n, 3), np.nan)
        scale = np.full(n, np.nan)
        for i, f in enumerate(self.frames):
            if f.landmarks is not None:
                landmarks[i] = f.landmarks
                rotation[i], translation[i], scale[i] = f.pose.rotation, f.pose.translation, f.pose.scale
        np.savez_compressed(
            path, landmarks=landmarks, found=np.array([f.landmarks is not None for f in self.frames]),
            pose_rotation=rotation, pose_translation=translation, pose_scale=scale,
            params=np.array([f.params for f in self.frames]), names=np.array(self.header.names),
            fps=self.video.fps, width=self.video.size[0], height=self.video.size[1])
