"""The receiver at the sizes people call at, per stage, against FFmpeg's H.264 decoder in the same run.

The bundled clip (a talking head, 360x288, 3 s), scaled with its aspect kept and padded to each
size (256 high, 512 high, 1280x720, 1920x1080), stored losslessly; the speaker enrolled from it
(fd-enroll's defaults) and sent at fd-send's defaults. Timed with one thread each (Numba,
OpenCV, FFmpeg): fd-send's session (tracking, fit, coding) on the frames held decoded, as a camera
hands them over, its setup apart (loading the face, building its models: once a call), and again
reading the clip coded as H.264 (as a user's file comes), setup included; the library's decoder drawing
the whole picture at the clip's size, with the time per stage (stream decoding, deformation,
scene mesh, background warp, rasteriser, the rest: retexturing, the session's bookkeeping);
and FFmpeg decoding the same frames coded as H.264 (libx264, its defaults, one thread) to
nothing. The figure that travels between machines is the ratio of the two decoders' rates.

    .venv/bin/python benchmarks/bench_hd.py [--sizes 256 512 720 1080] [--out results/]
"""

import json
import os
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import cv2  # noqa: E402  (after the thread settings, which these read on import)

from facedeform.common.cli import ArgumentParser, run_main

cv2.setNumThreads(1)

ROOT = Path(__file__).resolve().parents[1]
CLIP = ROOT / "samples" / "grid_bbaf2n.mpg"
LOOPS = 20  # passes of FFmpeg over the clip
SIZES = {256: (320, 256), 512: (640, 512), 720: (1280, 720), 1080: (1920, 1080)}
STAGES = {  # what each stage's time is spent in: (module, class, method)
    "decode": ("facedeform.protocol.decoder", "ByteStreamDecoder", "feed"),
    "deform": ("facedeform.codec.model.deform", "Deformer", "deform_extended"),
    "scene mesh": ("facedeform.codec.render.picture", "SceneMesh", "positions"),
    "background warp": ("facedeform.receiver.face_view", "PictureView", "_move_background"),
    "rasterise": ("facedeform.codec.render.render", "Renderer", "_render"),
}


def ffmpeg() -> str:
    from facedeform.experiment.baselines import ffmpeg as exe

    return exe()


def make_clip(size: tuple[int, int], folder: Path) -> tuple[Path, Path]:
    """(lossless clip, its H.264) of the bundled clip at ``size``, aspect kept, padded."""
    width, height = size
    lossless, h264 = folder / f"clip_{height}.mkv", folder / f"clip_{height}.mp4"
    scale = f"scale=-2:{height}:flags=lanczos,pad={width}:{height}:(ow-iw)/2:0"
    subprocess.run([ffmpeg(), "-v", "error", "-y", "-i", str(CLIP), "-vf", scale, "-c:v", "ffv1", str(lossless)],
                   check=True)
    subprocess.run([ffmpeg(), "-v", "error", "-y", "-i", str(lossless), "-c:v", "libx264", "-threads", "1",
                    "-pix_fmt", "yuv420p", str(h264)], check=True)
    return lossless, h264


def h264_fps(path: Path) -> tuple[float, int]:
    """(frames per second of CPU time FFmpeg takes to decode ``path`` on one thread, frames of one
    pass): the clip decoded LOOPS times over, so that the time is long enough to measure."""
    out = subprocess.run([ffmpeg(), "-benchmark", "-threads", "1", "-stream_loop", str(LOOPS - 1), "-i", str(path),
                          "-f", "null", "-"], capture_output=True, text=True, check=True).stderr
    frames = int(out.rsplit("frame=", 1)[1].split()[0])
    utime = float(out.split("utime=")[1].split("s")[0])
    return frames / utime, frames // LOOPS


def timed_stages(totals: dict) -> list:
    """Wraps each stage's method to add its CPU time to ``totals``; returns what to undo."""
    import importlib

    undo = []
    for stage, (module, cls, method) in STAGES.items():
        owner = getattr(importlib.import_module(module), cls)
        original = getattr(owner, method)

        def wrapped(*args, _original=original, _stage=stage, **kwargs):
            start = time.process_time()
            try:
                return _original(*args, **kwargs)
            finally:
                totals[_stage] += time.process_time() - start

        setattr(owner, method, wrapped)
        undo.append((owner, method, original))
    return undo


class HeldFrames:
    """A source of frames already decoded, as a camera hands them over: the sender's own work timed
    without the clip's decoding (FFV1 at 1920x1080 costs more CPU time than the sender's tracking)."""

    def __init__(self, source) -> None:
        self.fps, self.size = source.fps, source.size
        self._frames = list(source.frames())

    def frames(self):
        return iter(self._frames)


def send(source, face, bitrate: float | None = None) -> tuple[list, int, float, float]:
    """(chunks, frames, CPU seconds to set the session up, CPU seconds of its frames) of fd-send's
    session over ``source`` (a path or a source), at fd-send's defaults or ``bitrate`` bit/s."""
    from facedeform.protocol.stream import frame_bytes
    from facedeform.sender.config import SendConfig
    from facedeform.sender.session import SendSession

    start = time.process_time()
    session = SendSession(source, SendConfig(embed_face=False, bitrate=bitrate), face=face)
    ready = time.process_time()
    chunks = [frame_bytes(p, session.sealed) for p in session.packets() if p]
    return chunks, session.frame_count, ready - start, time.process_time() - ready


def with_layer(held: HeldFrames, face, bitrate: float) -> dict:
    """Sender and receiver frames a second with the picture layer at ``bitrate`` bit/s (the second pass)."""
    import facedeform

    for _ in range(2):
        chunks, frames, _, send_cpu = send(held, face, bitrate)
    start = time.process_time()
    drawn = sum(1 for _ in facedeform.decode(chunks, face))
    receive_cpu = time.process_time() - start
    return {"kbit_s": bitrate / 1000, "sender_fps": frames / send_cpu, "receiver_fps": drawn / receive_cpu}


def run(height: int, folder: Path, layer: float | None) -> dict:
    import facedeform
    from facedeform.sender.sources import VideoSource

    lossless, h264 = make_clip(SIZES[height], folder)
    face = facedeform.enroll(str(lossless))
    held = HeldFrames(VideoSource(lossless))
    send(held, face)  # the first pass loads the machine code, as the receiver's below
    chunks, frames, setup_cpu, send_cpu = send(held, face)
    *_, file_setup, file_cpu = send(str(h264), face)
    sum(1 for _ in facedeform.decode(chunks, face))  # compiled and warm
    totals: dict = defaultdict(float)
    undo = timed_stages(totals)
    start = time.process_time()
    drawn = sum(1 for _ in facedeform.decode(chunks, face))  # each frame let go, as a receiver's output does
    receive_cpu = time.process_time() - start
    for owner, method, original in undo:
        setattr(owner, method, original)
    ours = drawn / receive_cpu
    theirs, count = h264_fps(h264)
    if count != drawn:
        raise SystemExit(f"FFmpeg decoded {count} frames, we drew {drawn}: not comparable")
    ms = {stage: 1000 * t / drawn for stage, t in totals.items()}
    ms["rest"] = 1000 * receive_cpu / drawn - sum(ms.values())
    return {"size": f"{SIZES[height][0]}x{height}", "sender_fps": frames / send_cpu,
            "sender_fps_h264_file": frames / (file_setup + file_cpu), "sender_setup_ms": 1000 * setup_cpu,
            "receiver_fps": ours,
            "h264_fps": theirs, "ratio": ours / theirs, "ms_per_stage": ms,
            "layer": None if layer is None else with_layer(held, face, 1000 * layer)}


def main() -> None:
    p = ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+", default=list(SIZES), choices=list(SIZES))
    p.add_argument("--out", type=Path, default=Path("results"))
    p.add_argument("--layer", type=float, metavar="KBPS",
                   help="also time sender and receiver with the picture layer at this rate (kbit/s; at 1920x1080 "
                        "the layer pays from about 50)")
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory(prefix="fd-hd-") as tmp:
        for height in args.sizes:
            rows.append(row := run(height, Path(tmp), args.layer))
            print(json.dumps(row), file=sys.stderr, flush=True)
    (args.out / "hd.json").write_text(json.dumps(rows, indent=1) + "\n")
    stages = [*STAGES, "rest"]
    print("| size | sender fps | sender fps, H.264 file | receiver fps | H.264 fps | ratio | "
          + " | ".join(f"{s} ms" for s in stages) + " |")
    print("|---" * (6 + len(stages)) + "|")
    for r in rows:
        print(f"| {r['size']} | {r['sender_fps']:.0f} | {r['sender_fps_h264_file']:.0f} | {r['receiver_fps']:.0f} | "
              f"{r['h264_fps']:.0f} | {r['ratio']:.2f} | "
              + " | ".join(f"{r['ms_per_stage'][s]:.2f}" for s in stages) + " |")
    for r in rows:
        if r["layer"] is not None:
            layer = r["layer"]
            print(f"with the picture layer at {r['size']}, {layer['kbit_s']:g} kbit/s: sender "
                  f"{layer['sender_fps']:.1f} frames/s, receiver {layer['receiver_fps']:.1f}")


if __name__ == "__main__":
    raise SystemExit(run_main("bench_hd.py", lambda: main() or 0))
