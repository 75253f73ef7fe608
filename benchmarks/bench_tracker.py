"""Tracker accuracy and speed against MediaPipe's own landmarks on the dev clips.

Prints a Markdown table: per clip, frames with a face (ours / reference), the
median and 95th-percentile x, y landmark distance in pixels over frames where
both found a face, tracking time per frame (video decoding excluded), and how
many times the detector ran.
"""

import time
from pathlib import Path

import cv2
import numpy as np

from facedeform.common.cli import run_main
from facedeform.sender.tracker import FaceTracker

DEV = Path(__file__).resolve().parents[2] / "shared" / "samples" / "dev"


def bench(clip: Path, reference: Path) -> str:
    with np.load(reference) as ref:
        found, landmarks = ref["found"], ref["landmarks"] * [ref["width"], ref["height"], ref["width"]]
    tracker = FaceTracker()
    cap = cv2.VideoCapture(str(clip))
    distances, ours, frames, seconds = [], 0, 0, 0.0
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        started = time.perf_counter()
        points = tracker.track(frame)
        seconds += time.perf_counter() - started
        if points is not None:
            ours += 1
            if frames < len(found) and found[frames]:
                distances.append(np.linalg.norm(points[:, :2] - landmarks[frames, :, :2], axis=1))
        frames += 1
    cap.release()
    d = np.concatenate(distances) if distances else np.array([np.nan])
    return (f"| {clip.name} | {frames} | {ours} / {int(found.sum())} | {np.median(d):.3f} | "
            f"{np.percentile(d, 95):.3f} | {1000 * seconds / max(frames, 1):.2f} | {tracker.detections} |")


def main() -> int:
    if not DEV.is_dir():
        print(f"{DEV}: no dev clips here, nothing to measure")
        return 0
    print("| clip | frames | with face (ours / ref) | median px | p95 px | ms/frame | detector runs |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for reference in sorted(DEV.glob("*.landmarks.npz")):
        clips = [c for c in DEV.glob(reference.name.removesuffix(".landmarks.npz") + ".*") if c != reference]
        if clips:
            print(bench(clips[0], reference), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(run_main("bench_tracker.py", lambda: main() or 0))
