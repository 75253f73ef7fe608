"""Sender benchmarks: speed at 640x480 and 1280x720 on one core, and per-clip bits and fidelity.

    python benchmarks/bench_sender.py speed      # frames/s: tracking, estimation (pose + fit), both
    python benchmarks/bench_sender.py clips      # bits/frame and geometry fidelity per dev clip and layout
    python benchmarks/bench_sender.py rd         # held-out fidelity against bits/frame, with the personal basis
    python benchmarks/bench_sender.py smoothing  # One Euro settings: a noisy still face against talking

Speed uses the bundled clip scaled to each height and padded to each width. The clip table uses the
dev clips in ../shared/samples/dev; fidelity is ``sender.fidelity`` (rms error over rms motion
about the neutral: 0 perfect, 1 a frozen face; and the rms error over inter-ocular distance) over
its 41 mouth and jaw landmarks, over all lower-face landmarks the layout's model moves and over the
upper-face ones. The rate-distortion column codes the fitted parameters as a stream at each quality
level and measures the parameters the decoder outputs.

``rd`` splits each clip in halves: the personal motion basis (sender/motion.py, as fd-enroll
learns it, over the paper's fit or over the rest face) comes from the first half only, and every
layout is measured on the second half (bits of that half coded as a stream of its own, fidelity
of the decoded parameters), so the personal figures are what a call made after enrolment would get. It writes
docs/results/rd_fidelity_s{smoothing}.csv and .png.
"""

import dataclasses
import sys
import time
from datetime import date
from functools import partial
from pathlib import Path

import cv2
import numpy as np

from facedeform.codec.model.deform import Deformer
from facedeform.codec.model.face_model import load_base_face
from facedeform.common.cli import ArgumentParser, run_main
from facedeform.common.parameters import LAYOUTS
from facedeform.protocol.quantise import DEAD_ZONE, DEFAULT_QUALITY, QUALITIES
from facedeform.protocol.stream import Frame, Header, PacketEncoder, StreamDecoder, frame_bytes, quality_for_bitrate
from facedeform.sender.analysis import FaceAnalyser, Smoothing
from facedeform.sender.calibrate import lip_gap
from facedeform.sender.enrolment import MOTION_PATTERNS
from facedeform.sender.fidelity import MOUTH_JAW_LANDMARKS, fidelity
from facedeform.sender.session import first_basis, first_frames, stream_header
from facedeform.sender.sources import VideoSource
from facedeform.sender.tracker import FaceTracker

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "samples" / "dev"
FACE_ID = load_base_face().content_id
SIZES = ((640, 480), (1280, 720))


class Replay:
    """A tracker that returns landmarks tracked earlier (so estimation is timed alone)."""

    def __init__(self) -> None:
        self.track = lambda landmarks: landmarks


def _cell(x) -> str:
    return f"{x.relative:.2f} ({x.error:.3f})"


def _header(names, fps, basis, quality):
    return stream_header(names, fps, FACE_ID, quality, basis=basis)


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
    print("| size | tracking fps | estimation fps: paper | mouth (default) | full "
          "| tracking + estimation fps (default) |")
    print("|---|---|---|---|---|---|")
    for size in SIZES:
        frames = padded(clip, size) * 4
        tracker = FaceTracker()
        tracker.track(frames[0])
        started = time.perf_counter()
        landmarks = [tracker.track(f) for f in frames]
        track_s = time.perf_counter() - started
        rates = {}
        for layout in ("paper", "mouth", "full"):
            analyser = FaceAnalyser(Replay(), face, 25.0, layout, neutral=0)
            list(analyser.run(landmarks[:1]))
            started = time.perf_counter()
            list(analyser.run(landmarks))
            rates[layout] = len(frames) / (time.perf_counter() - started)
        track = len(frames) / track_s
        both = 1.0 / (1.0 / track + 1.0 / rates["mouth"])
        print(f"| {size[0]}x{size[1]} | {track:.0f} | {rates['paper']:.0f} | {rates['mouth']:.0f} "
              f"| {rates['full']:.0f} | {both:.0f} |")


def code(header: Header, results, frames_per_packet: int = 2) -> tuple[float, np.ndarray]:
    """(bits per frame, (n, k) parameters the decoder outputs for the frames with a face): the
    results coded as a stream of their own and decoded again, so that the fidelity measured is
    the receiver's, whatever the encoder chose to send."""
    encoder = PacketEncoder(header, frames_per_packet)
    body = b"".join(frame_bytes(encoder.frame(r.params, r.landmarks is not None)) for r in results)
    body += frame_bytes(encoder.end())
    decoder = StreamDecoder()
    frames = [e for e in decoder.feed(frame_bytes(encoder.header()) + body) + decoder.close() if isinstance(e, Frame)]
    if len(frames) != len(results) or decoder.stats.damaged:
        raise RuntimeError(f"the stream decoded to {len(frames)} of {len(results)} frames")
    decoded = np.stack([f.params for f, r in zip(frames, results) if r.target is not None])
    return 8 * len(body) / len(results), decoded


def lag(params: np.ndarray, gap: np.ndarray, span: int = 5) -> float:
    """Frames by which theta lags the unfiltered lip gap: the cross-correlation peak, refined by a parabola."""
    a, b = ((x - x.mean()) / x.std() for x in (params, gap))
    n = len(a)
    c = np.array([np.mean(a[max(0, k):n + min(0, k)] * b[max(0, -k):n + min(0, -k)]) for k in range(-span, span + 1)])
    i = int(np.argmax(c))
    shift = 0.5 * (c[i - 1] - c[i + 1]) / (c[i - 1] - 2 * c[i] + c[i + 1]) if 0 < i < len(c) - 1 else 0.0
    return i - span + shift


def analyse(face, landmarks: list, fps: float, layout: str, smoothing: Smoothing):
    """(analyser, all FrameAnalysis, (n, 468, 3) targets and (n, k) params of the frames with a face)."""
    analyser = FaceAnalyser(Replay(), face, fps, layout, round(fps), smoothing=smoothing)
    results = list(analyser.run(landmarks))
    seen = [r for r in results if r.target is not None]
    return analyser, results, np.stack([r.target for r in seen]), np.stack([r.params for r in seen])


def dev_clips():
    """(video path, its VideoSource, tracked landmarks per frame) for each dev clip; exits without them,
    before any result file is opened."""
    paths = sorted(DEV.glob("*.landmarks.npz"))
    if not paths:
        sys.exit(f"bench_sender: no dev clips in {DEV} (the shared data sits beside the repository)")
    for path in paths:
        video = next(p for p in DEV.glob(path.name.replace(".landmarks.npz", ".*")) if p != path)
        source = VideoSource(video)
        tracker = FaceTracker()
        yield video, source, [tracker.track(f) for f in source.frames()]


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
    for video, source, landmarks in dev_clips():
        found = [lm is not None for lm in landmarks]
        gap = np.array([lip_gap(lm) for lm in landmarks if lm is not None])
        for layout in LAYOUTS:
            analyser, results, targets, params = analyse(face, landmarks, source.fps, layout, Smoothing(smoothing))
            names = analyser.names
            theta = np.array([r.params[0] for r, f in zip(results, found) if f])
            rd, bits_at = [], {}
            basis = first_basis(names, source.fps, first_frames(source.fps, results))
            for q in QUALITIES:
                bits_at[q], decoded = code(stream_header(names, source.fps, FACE_ID, q, basis=basis), results)
                rd.append(f"{bits_at[q]:.0f}: {fidelity(deformer, targets, decoded, names).relative:.2f}")
            print(f"| {video.stem} | {layout} | {bits_at[DEFAULT_QUALITY]:.1f} | "
                  f"{lag(theta, gap):+.2f} | {_cell(fidelity(deformer, targets, params, names))} | "
                  f"{_cell(fidelity(deformer, targets, params, names, analyser.fit.lower))} | "
                  f"{_cell(fidelity(deformer, targets, params, names, analyser.fit.upper_landmarks))} | "
                  f"{', '.join(rd)} |")


def half_taught(base, landmarks: list, fps: float, patterns: int, over: str = "rest"):
    """``base`` with the motion basis fd-enroll would learn from the first half of ``landmarks``
    (None if the half teaches no pattern): what a call after enrolment has."""
    from facedeform.sender.motion import learn_motion, residuals

    residual, vertices = residuals(landmarks[:len(landmarks) // 2], Replay(), base, fps, over)
    basis = learn_motion(residual, vertices, patterns, over)
    return None if basis is None else dataclasses.replace(base, motion=basis)


def rd(smoothing: float, patterns: tuple[int, ...], frames_per_packet: int, target_bits: float) -> None:
    import csv

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    base = load_base_face()
    rows = []
    print(f"smoothing {smoothing:g}; {frames_per_packet} frames per packet; second half of each clip; cells: "
          f"bits/frame: mouth-and-jaw fidelity (relative), quality 1..5, then the level fd-send --bitrate "
          f"chooses for {target_bits:g} bits/frame from the half's first second")
    print(f"| clip | layout | q1 | q2 | q3 | q4 | q5 | at {target_bits:g} bits |")
    print("|---|---|---|---|---|---|---|---|")
    for video, source, landmarks in dev_clips():
        half = len(landmarks) // 2
        layouts = [(name, base, name) for name in LAYOUTS]
        for over in ("paper", "rest"):
            for m in patterns:
                face = half_taught(base, landmarks, source.fps, m, over)
                if face is not None:
                    layouts.append(("personal", face, f"personal {m}/{over}"))
        for layout, face, label in layouts:
            deformer = Deformer(face)
            analyser, results, _, _ = analyse(face, landmarks, source.fps, layout, Smoothing(smoothing))
            test = results[half:]
            targets = np.stack([r.target for r in test if r.target is not None])
            cells = []
            sample = first_frames(source.fps, test)
            basis = first_basis(analyser.names, source.fps, sample)
            header_at = partial(_header, analyser.names, source.fps, basis)
            chosen = quality_for_bitrate(header_at, sample, target_bits * source.fps,
                                         frames_per_packet, DEAD_ZONE)
            for q, target in [(q, "") for q in QUALITIES] + [(chosen, target_bits)]:
                bits, decoded = code(header_at(q), test, frames_per_packet)
                fid = fidelity(deformer, targets, decoded, analyser.names).relative
                rows.append({"clip": video.stem, "layout": label, "quality": q, "target_bits": target,
                             "bits_per_frame": round(bits, 1), "fidelity": round(fid, 4)})
                cells.append(f"{bits:.0f}: {fid:.2f}" + (f" (q{q})" if target else ""))
            print(f"| {video.stem} | {label} | {' | '.join(cells)} |", flush=True)
    out = ROOT / "docs" / "results" / f"rd_fidelity_s{smoothing:g}"
    with open(out.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    clips_seen = sorted({r["clip"] for r in rows})
    fig, axes = plt.subplots(2, (len(clips_seen) + 1) // 2, figsize=(12, 7), sharex=True, sharey=True)
    for ax, clip in zip(axes.ravel(), clips_seen):
        for label in dict.fromkeys(r["layout"] for r in rows):
            mine = [r for r in rows if r["clip"] == clip and r["layout"] == label]
            line = ax.plot(*zip(*[(r["bits_per_frame"], r["fidelity"]) for r in mine if not r["target_bits"]]),
                           "o-", ms=3, label=label)[0]
            chosen = [(r["bits_per_frame"], r["fidelity"]) for r in mine if r["target_bits"]]
            ax.plot(*zip(*chosen), "*", ms=9, color=line.get_color())
        ax.axhline(0.25, color="grey", lw=0.5, ls="--")
        ax.axvline(target_bits, color="grey", lw=0.5, ls="--")
        ax.set_title(clip, fontsize=9)
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("bits per frame (quality 1..5, left to right)")
    for ax in axes[:, 0]:
        ax.set_ylabel("mouth and jaw error / motion")
    axes.ravel()[0].legend(fontsize=7)
    fig.suptitle(f"Held-out fidelity against rate, smoothing {smoothing:g}, {frames_per_packet} frames per "
                 f"packet (stars: fd-send --bitrate's choice for {target_bits:g} bits/frame; "
                 f"dashed: 0.25 and {target_bits:g} bits)")
    fig.tight_layout()
    fig.savefig(out.with_suffix(".png"), dpi=90)
    print(f"wrote {out}.csv and .png")


#: The One Euro settings the smoothing table compares.
SMOOTHINGS = (("off (--smoothing 0)", Smoothing(0.0)), ("speed gain 0.05", Smoothing(beta=0.05)),
              ("speed gain 0.3 (default)", Smoothing()), ("speed gain 1", Smoothing(beta=1.0)))
NOISE = (3.0, 5.0)  # grey levels of Gaussian camera noise on the still face


def smoothing_table() -> None:
    """A still face (the bundled clip's first frame repeated with camera noise, fd-send's defaults):
    the share of frames in which the receiver's picture changes, and bits per frame; talking (the
    dev clips' second halves, personal basis from the first, level 2, 4 frames per packet): the mouth
    and jaw's relative error and bits per frame, means over the clips."""
    base = load_base_face()
    frame = next(VideoSource(ROOT / "samples" / "grid_bbaf2n.mpg").frames())
    rng = np.random.default_rng(0)
    still = {}
    for sigma in NOISE:
        tracker = FaceTracker()
        still[sigma] = [tracker.track(np.clip(frame + rng.normal(0, sigma, frame.shape), 0, 255).astype(np.uint8))
                        for _ in range(100)]
    talking = [(source.fps, landmarks, half_taught(base, landmarks, source.fps, MOTION_PATTERNS))
               for _, source, landmarks in dev_clips()]
    print(f"{date.today()}; still: frames that change / bits per frame at each noise; talking: error / bits")
    print("| One Euro setting | " + " | ".join(f"still face, noise σ {s:g}" for s in NOISE) + " | talking |")
    print("|---|" + "---|" * (len(NOISE) + 1))
    for label, smoothing in SMOOTHINGS:
        cells = []
        for landmarks in still.values():
            analyser, results, _, _ = analyse(base, landmarks, 25.0, "auto", smoothing)
            test = results[25:]
            basis = first_basis(analyser.names, 25.0, first_frames(25.0, test))
            bits, shown = code(stream_header(analyser.names, 25.0, FACE_ID, basis=basis), test)
            cells.append(f"{np.mean(np.any(np.diff(shown, axis=0) != 0, axis=1)):.0%} / {bits:.1f}")
        errors, rates = [], []
        for fps, landmarks, face in talking:
            analyser, results, _, _ = analyse(face, landmarks, fps, "personal", smoothing)
            test = results[len(landmarks) // 2:]
            bits, decoded = code(stream_header(analyser.names, fps, FACE_ID, 2), test, 4)  # personal: no coding basis
            targets = np.stack([r.target for r in test if r.target is not None])
            errors.append(fidelity(Deformer(face), targets, decoded, analyser.names).relative)
            rates.append(bits)
        cells.append(f"{np.mean(errors):.2f} / {np.mean(rates):.1f}")
        print(f"| {label} | {' | '.join(cells)} |", flush=True)


def main() -> None:
    p = ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("what", choices=("speed", "clips", "rd", "smoothing"))
    p.add_argument("--smoothing", type=float, default=1.0)
    p.add_argument("--patterns", type=int, nargs="*", default=[8, 12], help="rd: motion basis sizes")
    p.add_argument("--frames-per-packet", type=int, default=2, help="rd: as fd-send's option (default 2)")
    p.add_argument("--target-bits", type=float, default=40.0, help="rd: bits per frame to aim at (default 40)")
    args = p.parse_args()
    if args.what == "speed":
        speed()
    elif args.what == "clips":
        clips(args.smoothing)
    elif args.what == "smoothing":
        smoothing_table()
    else:
        rd(args.smoothing, tuple(args.patterns), args.frames_per_packet, args.target_bits)


if __name__ == "__main__":
    raise SystemExit(run_main("bench_sender.py", lambda: main() or 0))
