"""How soon a call shows the whole picture, and what a minute of it costs, beside x264's and x265's floors.

For each clip (its 256x256 face crop, made as fd-experiment makes it, and its speaker's face
model as fd-enroll makes it from the crop: what a user sends with fd-send --face), the crop played
in a loop to one minute and sent by fd-send's session at each --bitrate with the face model in the
stream (fd-send --face) and without it (--face-by-id: the receiver holds it): the bytes before the
first whole-picture frame can be drawn (the header, the face model, the first frame's packets) and
the seconds they take on a link of exactly the call's rate; the whole minute's bytes. Beside them
x264 and x265 at their coarsest (CRF 51) on the same minute: its bytes and rate, and the bytes and
seconds of their first frame at that rate. And the face paced (fd-send --paced-face): the seconds
until the first frame drawn with its preview and with the face itself, and the minute's bytes.

    .venv/bin/python benchmarks/bench_call_start.py /path/to/dev/*.mp4 --rates 2 4 8 --out results/
"""

import json
from math import ceil
from pathlib import Path

import numpy as np

import facedeform
from facedeform.common.cli import ArgumentParser, run_main
from facedeform.experiment.baselines import CODECS, encode_decode
from facedeform.experiment.clips import crops
from facedeform.protocol.stream import Frame, Model, StreamDecoder

CALL = 60.0  # seconds
BASELINES = ("x264", "x265")


def ours(frames: list, fps: float, face, kbps: float, embed: bool) -> dict:
    """The call's bytes before its first whole-picture frame, sent at ``kbps``, and (with the face
    in the stream) in all."""
    chunks = facedeform.encode(frames, face, fps=fps, bitrate=1000 * kbps, embed_face=embed)
    first = len(next(chunks)) + len(next(chunks))  # the header (with the face model, if in the stream), a frame
    row = {"first_bytes": first, "first_seconds": 8 * first / (1000 * kbps)}
    if embed:
        row["call_bytes"] = first + sum(map(len, chunks))
    chunks.close()
    return row


def paced(frames: list, fps: float, face, kbps: float) -> dict:
    """The same call with its face paced (fd-send --paced-face): the bytes, and seconds at the call's rate,
    until the first frame drawn with the preview and with the face itself; the minute's bytes."""
    chunks = facedeform.encode(frames, face, fps=fps, bitrate=1000 * kbps, paced_face=True)
    decoder, read, row, waiting = StreamDecoder(), 0, {}, None
    for chunk in chunks:
        read += len(chunk)
        for event in decoder.feed(chunk):
            if isinstance(event, Model):
                waiting = "preview" if event.preview else "face"
            elif isinstance(event, Frame) and waiting is not None:
                row[f"{waiting}_bytes"], row[f"{waiting}_seconds"] = read, 8 * read / (1000 * kbps)
                waiting = None
    row["call_bytes"] = read
    return row


def theirs(frames: list, fps: float, codec: str, work: Path) -> dict:
    """The codec at its floor: the minute's bytes and rate, its first frame's bytes and seconds at that rate."""
    floor = CODECS[codec].coarsest
    whole = encode_decode(frames, fps, codec, floor, work / f"call.{CODECS[codec].suffix}")
    first = encode_decode(frames[:1], fps, codec, floor, work / f"first.{CODECS[codec].suffix}").coded_bytes
    rate = whole.bitrate(fps)
    return {"call_bytes": whole.coded_bytes, "kbit_per_s": rate / 1000, "first_bytes": first,
            "first_seconds": 8 * first / rate}


def main() -> None:
    p = ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("clips", nargs="+", type=Path)
    p.add_argument("--rates", type=float, nargs="+", default=[2, 4, 8], metavar="KBPS")
    p.add_argument("--out", type=Path, default=Path("results"))
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for clip, work in crops(args.clips):
        face = facedeform.enroll(str(clip.path))
        count = round(CALL * clip.fps)
        frames = (clip.frames * ceil(count / len(clip.frames)))[:count]
        row: dict = {"clip": clip.name, "face_bytes": len(face.data)}
        for kbps in args.rates:
            row[f"{kbps:g}k"] = {"in_stream": ours(frames, clip.fps, face, kbps, True),
                                 "by_id": ours(frames, clip.fps, face, kbps, False),
                                 "paced": paced(frames, clip.fps, face, kbps)}
        for codec in BASELINES:
            row[codec] = theirs(frames, clip.fps, codec, work)
        rows.append(row)
        print(json.dumps(row), flush=True)
    (args.out / "call_start.json").write_text(json.dumps(rows, indent=1) + "\n")
    print("| clip | face KB | " + " | ".join(f"{r:g} kbit/s: first frame KB, s (face held: s; paced: preview s, "
                                            "face s); minute KB (paced)" for r in args.rates)
          + " | " + " | ".join(f"{c} floor: kbit/s; first frame KB, s; minute KB" for c in BASELINES) + " |")
    print("|---" * (2 + len(args.rates) + len(BASELINES)) + "|")
    for row in rows:
        cells = [row["clip"], f"{row['face_bytes'] / 1000:.1f}"]
        for kbps in args.rates:
            inband, held, late = (row[f"{kbps:g}k"][k] for k in ("in_stream", "by_id", "paced"))
            cells.append(f"{inband['first_bytes'] / 1000:.1f}, {inband['first_seconds']:.1f} "
                         f"({held['first_seconds']:.2f}; {late.get('preview_seconds', float('nan')):.1f}, "
                         f"{late.get('face_seconds', float('nan')):.1f}); {inband['call_bytes'] / 1000:.1f} "
                         f"({late['call_bytes'] / 1000:.1f})")
        for codec in BASELINES:
            b = row[codec]
            cells.append(f"{b['kbit_per_s']:.1f}; {b['first_bytes'] / 1000:.1f}, {b['first_seconds']:.2f}; "
                         f"{b['call_bytes'] / 1000:.1f}")
        print("| " + " | ".join(cells) + " |")
    means = {k: np.mean([r[f"{k:g}k"]["in_stream"]["first_seconds"] for r in rows]) for k in args.rates}
    print("mean seconds to the first whole picture, face in the stream: "
          + ", ".join(f"{s:.1f} at {k:g} kbit/s" for k, s in means.items()))
    previews = {k: np.mean([r[f"{k:g}k"]["paced"].get("preview_seconds", np.nan) for r in rows]) for k in args.rates}
    print("the same, paced (the preview's): " + ", ".join(f"{s:.1f} at {k:g} kbit/s" for k, s in previews.items()))


if __name__ == "__main__":
    raise SystemExit(run_main("bench_call_start.py", lambda: main() or 0))
