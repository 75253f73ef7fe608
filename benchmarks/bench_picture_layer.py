"""The picture layer at several rates: what the rate buys, whether it is kept, and what it costs.

For each clip (its 256x256 face crop, made as fd-experiment makes it, and its speaker's face
model from the crop's first second, motion basis from its first half, as fd-experiment
enrols), fd-send's session at each --bitrate, then the library's decoder: kbit/s of the stream
after its header, the largest 2-second window's rate over the rate asked for (issue: within 10 %),
picture packets per second, PSNR (mean of R, G, B; mean and 5th percentile over frames) against the
crop, the sender's frames per second (tracking, fit, coding and its closed loop) and the
receiver's (decoding and drawing, the layer included), one thread each.

With ``--udp``, each rate also as fd-send sends it to ``udp://`` (a frame a datagram with copies
until the receiver reports a clean link, then lean: sender/link.py), to fd-recv's own datagram
decoder and drawing, reporting every 0.5 s of the call on a link that loses nothing: kbit/s
counts every datagram after the header.

    .venv/bin/python benchmarks/bench_picture_layer.py /path/to/dev/*.mp4 --rates 1.5 4 10 30 --out results/
"""

import json
import time
from pathlib import Path

import numpy as np

import facedeform
from facedeform.common.cli import ArgumentParser, run_main
from facedeform.common.parameters import MAX_COMPONENTS
from facedeform.experiment.clips import crops
from facedeform.experiment.metrics import psnr_rgb
from facedeform.experiment.reporting import ReportingReceiver
from facedeform.protocol.stream import frame_bytes
from facedeform.receiver.session import ReceiveSession
from facedeform.sender.config import SendConfig
from facedeform.sender.session import SendSession

WINDOW = 2.0  # seconds


def run(clip, face, kbps: float | None) -> dict:
    config = SendConfig(embed_face=False) if kbps is None else SendConfig(bitrate=1000 * kbps, embed_face=False)
    session = SendSession(str(clip.path), config, face=face)
    started, chunks, per_frame, sent = time.perf_counter(), [], [], 0
    for packets in session.packets():
        if packets:
            chunks.append(frame_bytes(packets, session.sealed))
        if len(chunks) > 1:
            total = 8 * (sum(map(len, chunks)) - len(chunks[0]))
            per_frame += [0] * (session.frame_count - len(per_frame))
            per_frame[-1] += total - sent
            sent = total
    send_s = time.perf_counter() - started
    started = time.perf_counter()
    drawn = list(facedeform.decode(chunks, face))
    receive_s = time.perf_counter() - started
    return measured(clip, session, kbps, per_frame, drawn, send_s, receive_s)


def run_udp(clip, face, kbps: float) -> dict:
    """As :func:`run`, over datagrams to a receiver that reports a clean link (the two ends' times
    together, as sender fps; receiver fps not measured)."""
    session = SendSession(str(clip.path), SendConfig(bitrate=1000 * kbps, embed_face=False, datagrams=True),
                          face=face, warn=lambda line: None)
    link, drawn = ReportingReceiver(session, clip.fps), []
    link.decoder.hold_model()  # (what fd-recv --face tells its decoder)

    class Keep:
        write, close = drawn.append, staticmethod(lambda: None)

    receiver = ReceiveSession(lambda fps, size: [Keep()], None, face.model, warn=lambda line: None)
    started, per_frame = time.perf_counter(), []
    for i, datagrams in enumerate(session.packets()):
        if i:  # after the header
            per_frame += [0] * (session.frame_count - len(per_frame))
            per_frame[-1] += 8 * sum(map(len, datagrams))
        for datagram in datagrams:
            receiver.handle(link.receive(datagram), 0.0)
    receiver.close()
    return measured(clip, session, kbps, per_frame, drawn, time.perf_counter() - started, None) | \
        {"setting": f"{kbps:g}k udp", "lean_frames": session.lean_frames}


def measured(clip, session, kbps, per_frame, drawn, send_s, receive_s) -> dict:
    n, window = len(clip.frames), max(1, round(WINDOW * clip.fps))
    bits = np.array(per_frame, dtype=np.float64)
    psnr = psnr_rgb(clip.frames, drawn)
    stats = session.stats()
    return {"clip": clip.name, "setting": "default" if kbps is None else f"{kbps:g}k",
            "kbit_per_s": float(bits.sum() * clip.fps / n / 1000),
            "window_ratio": None if kbps is None or len(bits) < window else
            float(np.convolve(bits, np.ones(window), "valid").max() / (1000 * kbps * WINDOW)),
            "packets_per_s": (stats["picture_packets"] or 0) * clip.fps / n,
            "psnr": float(psnr.mean()), "psnr_p5": float(np.percentile(psnr, 5)),
            "sender_fps": n / send_s, "receiver_fps": None if receive_s is None else n / receive_s}


def main() -> None:
    p = ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("clips", nargs="+", type=Path)
    p.add_argument("--rates", type=float, nargs="+", default=[1.5, 4, 10, 30], metavar="KBPS")
    p.add_argument("--out", type=Path, default=Path("results"))
    p.add_argument("--udp", action="store_true", help="each rate also over udp:// to a receiver that reports")
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for clip, _ in crops(args.clips):
        half = len(clip.frames) / 2 / clip.fps
        face = facedeform.enroll(str(clip.path), seconds=1.0, motion=MAX_COMPONENTS, motion_seconds=half)
        for kbps in [None, *args.rates]:
            rows.append(row := run(clip, face, kbps))
            print(json.dumps(row), flush=True)
            if args.udp and kbps is not None:
                rows.append(row := run_udp(clip, face, kbps))
                print(json.dumps(row), flush=True)
    (args.out / "picture_layer.json").write_text(json.dumps(rows, indent=1) + "\n")
    print("| setting | kbit/s | largest 2 s window / rate | picture packets/s | PSNR dB (5th pct.) | sender fps "
          "| receiver fps |")
    print("|---|---|---|---|---|---|---|")
    for setting in dict.fromkeys(r["setting"] for r in rows):
        same = [r for r in rows if r["setting"] == setting]
        ratio = [r["window_ratio"] for r in same if r["window_ratio"] is not None]
        mean = {k: np.mean([r[k] or np.nan for r in same]) for k in ("kbit_per_s", "packets_per_s", "psnr",
                                                                     "psnr_p5", "sender_fps", "receiver_fps")}
        print(f"| {setting} | {mean['kbit_per_s']:.2f} | {max(ratio):.3f} | {mean['packets_per_s']:.1f} | " if ratio
              else f"| {setting} | {mean['kbit_per_s']:.2f} | - | - | ", end="")
        print(f"{mean['psnr']:.2f} ({mean['psnr_p5']:.2f}) | {mean['sender_fps']:.0f} | {mean['receiver_fps']:.0f} |")


if __name__ == "__main__":
    raise SystemExit(run_main("bench_picture_layer.py", lambda: main() or 0))
