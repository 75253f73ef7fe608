"""Results as files a researcher can use: CSV and JSON rows, plots against bitrate, side-by-side videos."""

import csv
import json
from pathlib import Path

import numpy as np

#: metric column -> (axis label, higher is better)
PLOTTED = {
    "akd_aligned": ("AKD after alignment (÷ inter-ocular distance)", False),
    "mouth_akd_aligned": ("mouth AKD after alignment (÷ inter-ocular distance)", False),
    "opening_corr": ("mouth-opening correlation", True),
    "motion_fidelity": ("mouth and jaw motion error (÷ motion; 0 perfect, 1 frozen)", False),
    "psnr_face": ("PSNR in the face (dB)", True),
    "ssim_face": ("SSIM in the face", True),
    "psnr_face_aligned": ("PSNR in the face after alignment (dB)", True),
    "ssim_face_aligned": ("SSIM in the face after alignment", True),
}


def write_rows(rows: list[dict], out: Path) -> None:
    """results.csv and results.json: one row per run, the same columns."""
    columns = list(dict.fromkeys(k for row in rows for k in row))
    with open(out / "results.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    (out / "results.json").write_text(json.dumps(rows, indent=1, default=float) + "\n")


def plot(rows: list[dict], out: Path) -> list[Path]:
    """One PNG per metric and output size: every codec on one chart against bitrate (log scale)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    codecs = sorted({r["codec"] for r in rows})
    colours = dict(zip(codecs, plt.cm.tab20(np.arange(len(codecs)) % 20)))
    for size in sorted({r["size"] for r in rows}):
        for metric, (label, _) in PLOTTED.items():
            fig, ax = plt.subplots(figsize=(7, 4.5))
            for codec in codecs:
                for clip in sorted({r["clip"] for r in rows}):
                    pts = sorted((r["bitrate_bps"], r[metric]) for r in rows
                                 if r["codec"] == codec and r["clip"] == clip and r["size"] == size
                                 and np.isfinite(r[metric]))
                    if pts:
                        x, y = zip(*pts)
                        ax.plot(np.array(x) / 1000, y, "o-", color=colours[codec], alpha=0.8,
                                label=codec if clip == min(r["clip"] for r in rows if r["codec"] == codec) else None)
            ax.set_xscale("log")
            ax.set_xlabel("bitrate (kbit/s, per-frame stream; one-off bytes apart)")
            ax.set_ylabel(label)
            ax.set_title(f"{label} at {size}x{size}")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=8)
            path = out / f"{metric}_{size}.png"
            fig.tight_layout()
            fig.savefig(path, dpi=110)
            plt.close(fig)
            written.append(path)
    return written


def side_by_side(path: Path, fps: float, columns: list[tuple[str, list]]) -> None:
    """An mp4 of labelled columns (original | ours | baseline), one frame per input frame."""
    import cv2

    from receiver.output import open_writer

    frames = []
    for parts in zip(*(f for _, f in columns)):
        labelled = []
        for (label, _), image in zip(columns, parts):
            image = image.copy()  # the label must not land on the caller's frames
            cv2.putText(image, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
            labelled.append(image)
        frames.append(np.hstack(labelled))
    height, width = frames[0].shape[:2]
    writer = open_writer(str(path), fps, (width, height), None)
    for frame in frames:
        writer.write(frame)
    writer.close()
