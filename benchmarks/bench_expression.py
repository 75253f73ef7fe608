"""Expression against an oracle: how much of what a perfect expression model would give we get.

For each clip (its 256x256 face crop and its speaker's face model, made as fd-experiment makes
them: the face from the first second, motion basis from the first half), fd-send's defaults
(the speaker's face file held by the receiver, no picture layer; ``--params`` another layout, as
fd-send's), decoded by the library.
Beside it, drawn by the same view of the same face (reference picture, rings, background,
head pose and global motion as sent):

- oracle: the expression replaced by the tracked face itself (the sender's pose-free target,
  the tracker's 468 landmarks as a piecewise-affine warp of the picture): what a perfect
  expression model would give on that clip;
- frozen: the expression at rest: what no expression model gives;
- uncoded: the sender's parameters before quantisation (what the coding loses).

Reported per clip: kbit/s after the header; PSNR (mean of R, G, B) and SSIM of ours, the
oracle and the frozen face, and ``gap``, the oracle's PSNR less ours (dB); the mouth opening's
swing (5th to 95th percentile) and correlation, and the eye opening's correlation and swing (a
blink drawn shallower than the speaker's shows only in the swing), each against the original,
tracked by the same tracker on the original, ours and the oracle; whether the speaker blinks.
``fit swing``: the same swing on the meshes themselves (deformed by the unquantised fit against
the target), which tells the fit's loss from the coding's and the drawing's.

    .venv/bin/python benchmarks/bench_expression.py /path/to/dev/*.mp4 /path/to/dev/*.mpg --out results/
"""

import json
from pathlib import Path

import numpy as np

import facedeform
from facedeform.codec.model.deform import Deformer, extended_params
from facedeform.common.cli import ArgumentParser, run_main
from facedeform.common.parameters import MAX_COMPONENTS, PLACING_PARAMS
from facedeform.experiment import metrics
from facedeform.experiment.clips import crops, track
from facedeform.protocol.stream import frame_bytes
from facedeform.receiver.face_view import PictureView
from facedeform.sender.analysis import LAYOUT_NAMES
from facedeform.sender.calibrate import lip_gap
from facedeform.sender.config import SendConfig
from facedeform.sender.session import SendSession, stream_header


def send(clip, face, dump: Path, options: dict) -> tuple[list[bytes], float, tuple[str, ...]]:
    """(stream chunks, kbit/s after the header, parameter names) of fd-send with ``options``
    (SendConfig's fields; none: its defaults)."""
    session = SendSession(str(clip.path), SendConfig(embed_face=False, **options), dump=dump, face=face)
    chunks = [frame_bytes(packets, session.sealed) for packets in session.packets() if packets]
    session.close()
    kbps = 8 * sum(map(len, chunks[1:])) * clip.fps / len(clip.frames) / 1000
    return chunks, kbps, session.analyser.names


def drawn_beside(clip, face, names: tuple[str, ...], dump: Path) -> tuple[list, list, list, np.ndarray, np.ndarray]:
    """(oracle frames, frozen frames, uncoded frames, fit mesh lip gaps, target lip gaps) from the sender's dump."""
    with np.load(dump) as d:
        params, targets, found = d["params"], d["targets"].astype(np.float64), d["found"]
    header = stream_header(names, clip.fps, face.model.content_id)
    size = clip.frames[0].shape[1::-1]
    oracle_view, frozen_view, uncoded_view = (PictureView(header, face.model, size) for _ in range(3))
    placing = np.array([n in PLACING_PARAMS for n in names])  # head pose, camera and body
    deformer = Deformer(face.model, header.rule)
    oracle, frozen, uncoded, fit_gap = [], [], [], []
    for p, target, seen in zip(params, targets, found):
        oracle.append(oracle_view.render(p, shape=target if seen else None))
        uncoded.append(uncoded_view.render(p))
        frozen.append(frozen_view.render(np.where(placing, p, 0.0)))
        fit_gap.append(lip_gap(deformer.deform_extended(extended_params(names, np.where(placing, 0.0, p)))))
    target_gap = np.where(found, lip_gap(targets), np.nan)
    return oracle, frozen, uncoded, np.where(found, fit_gap, np.nan), target_gap


def run(clip, face, work: Path, options: dict) -> dict:
    dump = work / f"{clip.name}.npz"
    chunks, kbps, names = send(clip, face, dump, options)
    ours = list(facedeform.decode(chunks, face))
    oracle, frozen, uncoded, fit_gap, target_gap = drawn_beside(clip, face, names, dump)
    ref = clip.landmarks
    row: dict = {"clip": clip.name, "kbit_per_s": kbps, "blinks": metrics.blinks(ref)}
    for name, frames in (("ours", ours), ("uncoded", uncoded), ("oracle", oracle), ("frozen", frozen)):
        row[f"psnr_{name}"] = float(metrics.psnr_rgb(clip.frames, frames).mean())
        row[f"ssim_{name}"] = metrics.ssim(clip.frames, frames)
        if name != "frozen":
            dec = track(frames)
            row[f"swing_{name}"] = metrics.opening_swing(ref, dec)
            row[f"opening_corr_{name}"] = metrics.opening_correlation(ref, dec)
            row[f"eye_corr_{name}"] = metrics.eye_correlation(ref, dec)
            row[f"eye_swing_{name}"] = metrics.eye_swing(ref, dec)
    row["gap"] = row["psnr_oracle"] - row["psnr_ours"]
    row["fit_swing"] = metrics.swing(fit_gap) / metrics.swing(target_gap)
    return row


TABLE = (("kbit/s", "kbit_per_s", "{:.2f}"), ("PSNR ours", "psnr_ours", "{:.2f}"),
         ("oracle", "psnr_oracle", "{:.2f}"), ("frozen", "psnr_frozen", "{:.2f}"), ("gap", "gap", "{:.2f}"),
         ("SSIM ours", "ssim_ours", "{:.3f}"), ("oracle", "ssim_oracle", "{:.3f}"),
         ("mouth swing ours", "swing_ours", "{:.2f}"), ("oracle", "swing_oracle", "{:.2f}"),
         ("uncoded", "swing_uncoded", "{:.2f}"), ("fit", "fit_swing", "{:.2f}"),
         ("mouth corr ours", "opening_corr_ours", "{:.2f}"),
         ("oracle", "opening_corr_oracle", "{:.2f}"), ("eye corr ours", "eye_corr_ours", "{:.2f}"),
         ("uncoded", "eye_corr_uncoded", "{:.2f}"),
         ("oracle", "eye_corr_oracle", "{:.2f}"), ("eye swing ours", "eye_swing_ours", "{:.2f}"),
         ("uncoded", "eye_swing_uncoded", "{:.2f}"), ("oracle", "eye_swing_oracle", "{:.2f}"),
         ("blinks", "blinks", "{}"))


def main() -> None:
    p = ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("clips", nargs="+", type=Path)
    p.add_argument("--out", type=Path, default=Path("results"))
    p.add_argument("--bitrate", type=float, metavar="KBPS", help="fd-send --bitrate, the picture layer off "
                   "(default: fd-send's defaults, a quantiser level)")
    p.add_argument("--level", type=int, help="fd-send --level (default: fd-send's)")
    p.add_argument("--params", choices=LAYOUT_NAMES, default="auto", help="fd-send --params: the parameters sent "
                   "(default: %(default)s, the speaker's own motion basis; 'mouth' or 'paper' for the region rule's)")
    p.add_argument("--motion", type=int, default=MAX_COMPONENTS, help="fd-enroll --motion: most patterns in the "
                   "speaker's motion basis (default: %(default)s, as fd-experiment enrols)")
    args = p.parse_args()
    options: dict = {"layout": args.params} | ({} if args.level is None else {"level": args.level})
    if args.bitrate is not None:
        options.update(bitrate=1000 * args.bitrate, picture_layer=False)
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for clip, work in crops(args.clips):
        half = len(clip.frames) / 2 / clip.fps
        face = facedeform.enroll(str(clip.path), seconds=1.0, motion=args.motion, motion_seconds=half)
        rows.append(row := run(clip, face, work, options))
        print(json.dumps(row), flush=True)
    (args.out / "expression.json").write_text(json.dumps(rows, indent=1) + "\n")
    print("| clip | " + " | ".join(t for t, _, _ in TABLE) + " |")
    print("|---" * (len(TABLE) + 1) + "|")
    for row in rows:
        print(f"| {row['clip']} | " + " | ".join(f.format(row[k]) for _, k, f in TABLE) + " |")


if __name__ == "__main__":
    raise SystemExit(run_main("bench_expression.py", lambda: main() or 0))
