"""A paced face over UDP: how soon a receiver draws the speaker, on a clean link, a lossy one, a one-way
one, and joining late.

For each clip (its 256x256 face crop as fd-experiment makes it, the speaker's face model as
fd-enroll makes it from the crop), the crop played in a loop to one minute and sent by fd-send's
session as to ``udp://`` with ``--paced-face`` at each --bitrate, to a simulated receiver: fd-recv's
own datagram decoder, which loses each datagram with the case's probability, hears nothing before it
joins and, once it has the header, reports back every REPORT_EVERY seconds of the call as fd-recv
does (none on a one-way link). Reported per case: seconds from the receiver's start until it
holds the preview and the face, the call's kbit/s (every datagram sent, header included), the
face's bytes sent (its rounds included), and when the picture layer started.

    .venv/bin/python benchmarks/bench_paced_udp.py /path/to/dev/*.mp4 --rates 4 8 --out results/
"""

import json
import random
from pathlib import Path

import facedeform
from facedeform.common.cli import ArgumentParser, run_main
from facedeform.experiment.clips import crops
from facedeform.experiment.reporting import ReportingReceiver
from facedeform.protocol.framing import MODEL, PICTURE, SYNC, packet_type
from facedeform.protocol.stream import Model
from facedeform.sender.config import SendConfig
from facedeform.sender.session import SendSession
from facedeform.sender.sources import LoopedSource

CALL = 60.0  # seconds
CASES = {"reports": {}, "one-way": {"reports": False}, "joins at 20 s": {"join": 20.0},
         "joins at 20 s, one-way": {"join": 20.0, "reports": False}, "1 % lost": {"loss": 0.01}}


def kind(datagram: bytes) -> int | None:
    """The packet type of a datagram that is one packet of its own; None for a frames datagram."""
    return packet_type(datagram[1]) if datagram[0] == SYNC and len(datagram) > 1 else None


def call(path: Path, fps: float, face, kbps: float, reports: bool = True, join: float = 0.0,
         loss: float = 0.0, seed: int = 1) -> dict:
    session = SendSession(LoopedSource(str(path), CALL),
                          SendConfig(bitrate=1000 * kbps, paced_face=True, datagrams=True), face=face,
                          warn=lambda line: None)
    receiver, lose = ReportingReceiver(session, fps, reports), random.Random(seed)
    row: dict = {"preview_s": None, "face_s": None, "layer_from_s": None}
    sent = face_bytes = 0
    for datagrams in session.packets():
        now = session.frame_count / fps
        for datagram in datagrams:
            sent += len(datagram)
            face_bytes += len(datagram) * (kind(datagram) == MODEL)
            if kind(datagram) == PICTURE and row["layer_from_s"] is None:
                row["layer_from_s"] = round(now, 1)
            if now < join or lose.random() < loss:
                continue
            for event in receiver.receive(datagram):
                if isinstance(event, Model):
                    row["preview_s" if event.preview else "face_s"] = round(now - join, 1)
    session.close()
    return row | {"kbit_per_s": round(8 * sent / CALL / 1000, 2), "face_bytes_sent": face_bytes}


def main() -> None:
    p = ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("clips", nargs="+", type=Path)
    p.add_argument("--rates", type=float, nargs="+", default=[4, 8], metavar="KBPS")
    p.add_argument("--out", type=Path, default=Path("results"))
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for clip, _ in crops(args.clips):
        face = facedeform.enroll(str(clip.path))
        for kbps in args.rates:
            for case, options in CASES.items():
                row = {"clip": clip.name, "face_bytes": len(face.data), "kbps": kbps, "case": case,
                       **call(clip.path, clip.fps, face, kbps, **options)}
                rows.append(row)
                print(json.dumps(row), flush=True)
    (args.out / "paced_udp.json").write_text(json.dumps(rows, indent=1) + "\n")
    print("| clip | face KB | kbit/s asked | case | preview after, s | face after, s | kbit/s sent | face KB sent "
          "| layer from, s |")
    print("|---" * 9 + "|")
    for r in rows:
        print(f"| {r['clip']} | {r['face_bytes'] / 1000:.1f} | {r['kbps']:g} | {r['case']} | {r['preview_s']} "
              f"| {r['face_s']} | {r['kbit_per_s']} | {r['face_bytes_sent'] / 1000:.1f} | {r['layer_from_s']} |")


if __name__ == "__main__":
    raise SystemExit(run_main("bench_paced_udp.py", lambda: main() or 0))
