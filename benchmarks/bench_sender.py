"""Sender benchmarks: speed at 640x480 and 1280x720 on one core, and per-clip bits and fidelity.

    python benchmarks/bench_sender.py speed      # frames/s: tracking, estimation (pose + fit), both
    python benchmarks/bench_sender.py clips      # bits/frame at q3 and geometry fidelity per dev clip

Speed uses the bundled clip scaled to each height and padded to each width. The clip table uses the
dev clips in ../shared/samples/dev; fidelity is ``sender.fidelity`` over the
lower-face landmarks (mouth, cheeks, chin, jaw line) and the upper-face ones
(brows, lids, cheeks), relative error (0 perfect, 1 a frozen face) and
absolute error over inter-ocular distance.
"""

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from codec.deform import Deformer
from codec.face_model import load_base_face
from protocol.stream import Header, PacketEncoder, frame_bytes, steps_for
from sender.analysis import FaceAnalyser, Smoothing
from sender.calibrate import lip_gap
from sender.fidelity import fidelity
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


def bits_per_frame(names, results, fps: float) -> float:
    header = Header(fps, names, steps_for(names, 3), load_base_face().content_id, key_interval=round(fps))
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


def clips(smoothing: float) -> None:
    face = load_base_face()
    deformer = Deformer(face)
    print(f"smoothing {smoothing:g}; bits/frame at q3, 2 frames per packet; fidelity relative (absolute / IOD)")
    print("| clip | bits paper | bits full | theta lag (frames) | lower face, paper = full | upper face, paper | upper face, full |")
    print("|---|---|---|---|---|---|---|")
    for path in sorted(DEV.glob("*.landmarks.npz")):
        video = next(p for p in DEV.glob(path.name.replace(".landmarks.npz", ".*")) if p != path)
        source = VideoSource(video)
        tracker = FaceTracker()
        landmarks = [tracker.track(f) for f in source.frames()]
        row = {}
        for layout in ("paper", "full"):
            analyser = FaceAnalyser(Replay(), face, source.fps, layout, round(source.fps),
                                    smoothing=Smoothing(smoothing))
            results = list(analyser.run(landmarks))
            seen = [r for r in results if r.target is not None]
            targets, params = np.stack([r.target for r in seen]), np.stack([r.params for r in seen])
            row[layout] = (bits_per_frame(analyser.names, results, source.fps),
                           fidelity(deformer, targets, params, analyser.names, analyser.fit.lower),
                           fidelity(deformer, targets, params, analyser.names, analyser.fit.upper_landmarks))
            if layout == "paper":
                found = [lm is not None for lm in landmarks]
                theta = np.array([r.params[0] for r, f in zip(results, found) if f])
                row["lag"] = lag(theta, np.array([lip_gap(lm) for lm in landmarks if lm is not None]))
        f = lambda x: f"{x.relative:.2f} ({x.error:.3f})"
        print(f"| {video.stem} | {row['paper'][0]:.1f} | {row['full'][0]:.1f} | {row['lag']:+.2f} | "
              f"{f(row['paper'][1])} | {f(row['paper'][2])} | {f(row['full'][2])} |")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("what", choices=("speed", "clips"))
    p.add_argument("--smoothing", type=float, default=1.0)
    args = p.parse_args()
    speed() if args.what == "speed" else clips(args.smoothing)


if __name__ == "__main__":
    main()
