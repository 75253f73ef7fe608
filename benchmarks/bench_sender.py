"""Sender benchmarks: speed at 640x480 and 1280x720 on one core, and per-clip bits and fidelity.

    python benchmarks/bench_sender.py speed      # frames/s: tracking, estimation (pose + fit), both
    python benchmarks/bench_sender.py clips      # bits/frame and geometry fidelity per dev clip and layout

Speed uses the bundled clip scaled to each height and padded to each width. The clip table uses the
dev clips in ../shared/samples/dev; fidelity is ``sender.fidelity`` (rms error over rms motion
about the neutral: 0 perfect, 1 a frozen face; and the rms error over inter-ocular distance) over
its 41 mouth and jaw landmarks, over all lower-face landmarks the layout's model moves and over the
upper-face ones. The rate-distortion column quantises the fitted parameters at each quality level
(the decoder's values; the encoder's skip of static frames is not applied to the fidelity).
"""

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from codec.deform import Deformer
from codec.face_model import load_base_face
from protocol.stream import Header, PacketEncoder, frame_bytes, steps_for
from protocol.quantise import QUALITIES
from sender.analysis import LAYOUTS, FaceAnalyser, Smoothing
from sender.calibrate import lip_gap
from sender.fidelity import MOUTH_JAW_LANDMARKS, fidelity
from sender.sources import VideoSource
from sender.tracker import FaceTracker

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "samples" / "dev"
SIZES = ((640, 480), (1280, 720))


class Replay:
    """A tracker that returns landmarks tracked earlier (so estimation is timed alone)."""

    def __init__(self) -> None:
        self.track = lambda landmarks: landmarks


def padded(frames: list[np.ndarray], size: tuple[int, int]) -> list[np.ndarray]:
    w, h = size
    out = []
    for f in frames:
        f = cv2.resize(f, None, fx=h / f.shape[0], fy=h / f.shape[0], interpolation=cv2.INTER_LINEAR)
        canvas = np.full((h, w, 3), 60, np.uint8)
        y, x = (h - f.shape[0]) // 2, (w - f.shape[1]) // 2
        canvas[y:y + f.shape[0], x:x + f.shape[1]] = f
        out.append(canvas)
    return out


def speed() -> None:
    cv2.setNumThreads(1)
    clip = list(VideoSource(ROOT / "samples" / "grid_bbaf2n.mpg").frames())
    face = load_base_face()
    print("| size | tracking fps | estimation fps (paper) | estimation fps (full) | tracking + estimation fps |")
    print("|---|---|---|---|---|")
    for size in SIZES:
        frames = padded(clip, size) * 4
        tracker = FaceTracker()
        tracker.track(frames[0])
        started = time.perf_counter()
        landmarks = [tracker.track(f) for f in frames]
        track_s = time.perf_counter() - started
        rates = {}
        for layout in ("paper", "full"):
            analyser = FaceAnalyser(Replay(), face, 25.0, layout, neutral=0)
            list(analyser.run(landmarks[:1]))
            started = time.perf_counter()
            list(analyser.run(landmarks))
            rates[layout] = len(frames) / (time.perf_counter() - started)
        track = len(frames) / track_s
        both = 1.0 / (1.0 / track + 1.0 / rates["paper"])
        print(f"| {size[0]}x{size[1]} | {track:.0f} | {rates['paper']:.0f} | {rates['full']:.0f} | {both:.0f} |")


def bits_per_frame(names, results, fps: float, quality: int = 3) -> float:
    header = Header(fps, names, steps_for(names, quality), load_base_face().content_id, key_interval=round(fps))
    encoder = PacketEncoder(header, 2)
    total = sum(len(frame_bytes(encoder.frame(r.params, r.landmarks is not None))) for r in results)
    return 8 * (total + len(frame_bytes(encoder.end()))) / len(results)


def lag(params: np.ndarray, gap: np.ndarray, span: int = 5) -> float:
    """Frames by which theta lags the unfiltered lip gap: the cross-correlation peak, refined by a parabola."""
    a, b = ((x - x.mean()) / x.std() for x in (params, gap))
    n = len(a)
    c = np.array([np.mean(a[max(0, k):n + min(0, k)] * b[max(0, -k):n + min(0, -k)]) for k in range(-span, span + 1)])
    i = int(np.argmax(c))
    shift = 0.5 * (c[i - 1] - c[i + 1]) / (c[i - 1] - 2 * c[i] + c[i + 1]) if 0 < i < len(c) - 1 else 0.0
    return i - span + shift


def analyse(face, landmarks: list, fps: float, layout: str, smoothing: float):
    """(analyser, all FrameAnalysis, (n, 468, 3) targets and (n, k) params of the frames with a face)."""
    analyser = FaceAnalyser(Replay(), face, fps, layout, round(fps), smoothing=Smoothing(smoothing))
    results = list(analyser.run(landmarks))
    seen = [r for r in results if r.target is not None]
    return analyser, results, np.stack([r.target for r in seen]), np.stack([r.params for r in seen])


def clips(smoothing: float) -> None:
    face = load_base_face()
    deformer = Deformer(face)
    print(f"smoothing {smoothing:g}; 2 frames per packet; fidelity relative (absolute / IOD): mouth and jaw = "
          f"the {len(MOUTH_JAW_LANDMARKS)} landmarks of sender.fidelity (rms), lower and upper face = all the "
          "landmarks each model moves; rate-distortion: bits/frame and mouth-and-jaw fidelity of the "
          "quantised parameters at quality 1..5")
    print("| clip | layout | bits q3 | theta lag (frames) | mouth and jaw | lower face | upper face | "
          "rate-distortion q1..q5 (bits: fidelity) |")
    print("|---|---|---|---|---|---|---|---|")
    for path in sorted(DEV.glob("*.landmarks.npz")):
        video = next(p for p in DEV.glob(path.name.replace(".landmarks.npz", ".*")) if p != path)
        source = VideoSource(video)
        tracker = FaceTracker()
        landmarks = [tracker.track(f) for f in source.frames()]
        found = [lm is not None for lm in landmarks]
        gap = np.array([lip_gap(lm) for lm in landmarks if lm is not None])
        for layout in LAYOUTS:
            analyser, results, targets, params = analyse(face, landmarks, source.fps, layout, smoothing)
            names = analyser.names
            theta = np.array([r.params[0] for r, f in zip(results, found) if f])
            rd = []
            for q in QUALITIES:
                steps = steps_for(names, q)
                decoded = np.rint(params / steps) * steps
                rd.append(f"{bits_per_frame(names, results, source.fps, q):.0f}: "
                          f"{fidelity(deformer, targets, decoded, names).relative:.2f}")
            f = lambda x: f"{x.relative:.2f} ({x.error:.3f})"
            print(f"| {video.stem} | {layout} | {bits_per_frame(names, results, source.fps):.1f} | "
                  f"{lag(theta, gap):+.2f} | {f(fidelity(deformer, targets, params, names))} | "
                  f"{f(fidelity(deformer, targets, params, names, analyser.fit.lower))} | "
                  f"{f(fidelity(deformer, targets, params, names, analyser.fit.upper_landmarks))} | "
                  f"{', '.join(rd)} |")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("what", choices=("speed", "clips"))
    p.add_argument("--smoothing", type=float, default=1.0)
    args = p.parse_args()
    speed() if args.what == "speed" else clips(args.smoothing)


if __name__ == "__main__":
    main()
