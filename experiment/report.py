"""Results as files a researcher can use: CSV and JSON rows, plots against bitrate, side-by-side videos."""

import csv
import json
from pathlib import Path

import numpy as np

#: metric column -> (axis label, higher is better)
PLOTTED = {
    "psnr": ("PSNR, mean of R, G, B (dB)", True),
    "psnr_p5": ("PSNR, 5th percentile over frames (dB)", True),
    "ssim": ("SSIM (luma)", True),
    "ms_ssim": ("MS-SSIM (luma)", True),
    "vmaf": ("VMAF (default model)", True),
    "akd": ("AKD (÷ inter-ocular distance)", False),
    "mouth_akd": ("mouth AKD (÷ inter-ocular distance)", False),
    "mouth_akd_aligned": ("mouth AKD after alignment (÷ inter-ocular distance)", False),
    "opening_corr": ("mouth-opening correlation", True),
    "eye_corr": ("eye-opening correlation", True),
    "motion_fidelity": ("mouth and jaw motion error (÷ motion; 0 perfect, 1 frozen)", False),
}
OVERVIEW = ("vmaf", "psnr", "ms_ssim", "mouth_akd")  # the four panels of overview_<size>.png


def write_rows(rows: list[dict], out: Path) -> None:
    """results.csv and results.json: one row per run, the same columns."""
    columns = list(dict.fromkeys(k for row in rows for k in row))
    with open(out / "results.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    (out / "results.json").write_text(json.dumps(rows, indent=1, default=float) + "\n")


def curves(rows: list[dict], size: int, metric: str) -> dict:
    """codec -> (x kbit/s, y) means over the clips of each setting, in rate order; our runs also as
    '<codec> + one-off' with the one-off bytes spread over 250 frames."""
    out = {}
    for codec in sorted({r["codec"] for r in rows}):
        for rate, suffix in (("bitrate_bps", ""), ("bitrate_oneoff_bps", " + one-off")):
            if suffix and not codec.startswith("ours"):
                continue
            points = []
            for setting in sorted({r["setting"] for r in rows if r["codec"] == codec}):
                same = [r for r in rows if r["codec"] == codec and r["setting"] == setting and r["size"] == size
                        and np.isfinite(r.get(metric, np.nan))]  # rows of an older run may lack a newer measure
                if same:
                    points.append((np.mean([r[rate] for r in same]) / 1000, np.mean([r[metric] for r in same])))
            if points:
                out[codec + suffix] = tuple(np.array(v) for v in zip(*sorted(points)))
    return out


def _draw(ax, rows: list[dict], size: int, metric: str, colours: dict) -> None:
    """One measure against kbit/s (log axis), a line per codec, means over the clips."""
    for name, (x, y) in curves(rows, size, metric).items():
        codec = name.removesuffix(" + one-off")
        ax.plot(x, y, "o--" if name != codec else "o-", color=colours[codec], alpha=0.85, label=name,
                markersize=4)
    from matplotlib.ticker import FixedLocator, NullFormatter, ScalarFormatter

    ax.set_xscale("log")
    ax.xaxis.set_major_locator(FixedLocator([0.5, 1, 2, 4, 10, 20, 40, 100, 200, 400]))
    ax.xaxis.set_major_formatter(ScalarFormatter())
    ax.xaxis.set_minor_formatter(NullFormatter())  # the minor ticks' own labels overlapped
    ax.set_xlabel("kbit/s (log)")
    ax.set_ylabel(PLOTTED[metric][0])
    ax.grid(True, which="both", alpha=0.3)


def plot(rows: list[dict], out: Path) -> list[Path]:
    """A PNG per measure and size, every codec on one chart against kbit/s on a log axis (means over the
    clips), and overview_<size>.png with four of them."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    codecs = sorted({r["codec"] for r in rows})
    colours = dict(zip(codecs, plt.cm.tab10(np.arange(len(codecs)) % 10)))
    clips = len({r["clip"] for r in rows})
    for size in sorted({r["size"] for r in rows}):
        for metric, (label, _) in PLOTTED.items():
            fig, ax = plt.subplots(figsize=(7, 4.5))
            _draw(ax, rows, size, metric, colours)
            ax.set_title(f"{label} at {size}x{size}, mean of {clips} clip(s)")
            ax.legend(fontsize=8)
            written.append(_save(fig, out / f"{metric}_{size}.png"))
        fig, axes = plt.subplots(2, 2, figsize=(12, 8))
        for ax, metric in zip(axes.flat, OVERVIEW):
            _draw(ax, rows, size, metric, colours)
        axes.flat[0].legend(fontsize=8)
        fig.suptitle(f"Whole decoded picture against the {size}x{size} face crop, mean of {clips} clip(s); "
                     "dashed: ours with the one-off bytes spread over 250 frames")
        written.append(_save(fig, out / f"overview_{size}.png"))
    return written


def _save(fig, path: Path) -> Path:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


TABLED = ("psnr", "psnr_p5", "ssim", "ms_ssim", "vmaf", "mouth_akd", "opening_corr", "faces_found")


def bd_rate(ours: tuple[np.ndarray, np.ndarray], theirs: tuple[np.ndarray, np.ndarray]) -> float | None:
    """Bjontegaard rate difference in percent: how many more bits (negative: fewer) ``ours`` needs
    than ``theirs`` for the same quality, averaged over the quality range both curves cover; each
    curve (kbit/s, quality) is interpolated in log-rate by monotone cubic (PCHIP) pieces. None
    where the curves do not overlap or either has fewer than two distinct qualities."""
    from scipy.interpolate import PchipInterpolator

    def log_rate(curve):
        rate, quality = (np.asarray(v, dtype=np.float64) for v in curve)
        order = np.argsort(quality)
        quality, rate = quality[order], rate[order]
        keep = np.concatenate([[True], np.diff(quality) > 0])
        return (PchipInterpolator(quality[keep], np.log10(rate[keep])), quality[keep]) if keep.sum() >= 2 else None

    a, b = log_rate(ours), log_rate(theirs)
    if a is None or b is None:
        return None
    low, high = max(a[1][0], b[1][0]), min(a[1][-1], b[1][-1])
    if not high > low:
        return None
    grid = np.linspace(low, high, 101)
    return float(100.0 * (10.0 ** np.mean(a[0](grid) - b[0](grid)) - 1.0))


def bd_table(rows: list[dict], ours: str = "ours-auto-own") -> str:
    """Markdown: per size, the BD-rate of ``ours`` (every setting run: quality levels and rates)
    against each baseline, on PSNR and on VMAF, over the clips' mean curves."""
    lines = ["| size | against | BD-rate, PSNR | BD-rate, VMAF |", "|---|---|---|---|"]
    for size in sorted({r["size"] for r in rows}):
        by_metric = {m: curves(rows, size, m) for m in ("psnr", "vmaf")}
        if ours not in by_metric["psnr"]:
            continue
        for codec in sorted(c for c in by_metric["psnr"] if not c.startswith("ours")):
            cells = []
            for metric in ("psnr", "vmaf"):
                value = bd_rate(by_metric[metric][ours], by_metric[metric][codec])
                single = len(by_metric[metric][codec][0]) < 2  # a floor alone is a point, not a curve
                cells.append(("one setting: run --rungs 2 or more" if single else "no overlap") if value is None
                             else f"{value:+.0f} %")
            lines.append(f"| {size} | {codec} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def headline(rows: list[dict]) -> str:
    """The setting of ours that the table and the side-by-side video show: fd-send's default level
    ("l3") if it was run, else our lowest rate."""
    if any(r["setting"] == "l3" for r in rows):
        return "l3"
    return min(rows, key=lambda r: r["bitrate_bps"])["setting"]


def table(rows: list[dict]) -> str:
    """Markdown: per size, our default settings (fd-send's auto parameters, quality 3, own face) and
    each baseline at its floor (its coarsest setting) and at the setting whose rate is nearest 3 times
    the floor's; means over the clips."""
    def mean(same: list, key: str) -> float:
        return float(np.mean([r[key] for r in same]))

    head = ("| size | codec, setting | kbit/s (+ one-off) | PSNR dB | PSNR p5 | SSIM | MS-SSIM | VMAF | mouth AKD "
            "| opening corr. | faces found | encode / decode fps |\n" + "|---" * 12 + "|\n")
    lines = []
    for size in sorted({r["size"] for r in rows}):
        at = [r for r in rows if r["size"] == size]
        picks = []
        own = [r for r in at if r["codec"] == "ours-auto-own"]
        if own:
            setting = headline(own)
            picks.append((f"ours, auto, {setting}, own face", [r for r in own if r["setting"] == setting]))
        for codec in sorted({r["codec"] for r in at if not r["codec"].startswith("ours")}):
            settings: dict[str, list] = {}
            for r in at:
                if r["codec"] == codec:
                    settings.setdefault(r["setting"], []).append(r)
            by_rate = sorted(settings.items(), key=lambda kv: mean(kv[1], "bitrate_bps"))
            floor = by_rate[0]
            picks.append((f"{codec} {floor[0]} (floor)", floor[1]))
            near = min(by_rate[1:], key=lambda kv: abs(mean(kv[1], "bitrate_bps") - 3 * mean(floor[1], "bitrate_bps")),
                       default=None)
            if near:
                picks.append((f"{codec} {near[0]} (~3x floor)", near[1]))
        for label, same in picks:
            rate = f"{mean(same, 'bitrate_bps') / 1000:.2f}"
            if same[0]["oneoff_bytes"]:
                rate += f" ({mean(same, 'bitrate_oneoff_bps') / 1000:.2f})"
            cells = [f"{mean(same, k):.3f}" if k in ("ssim", "ms_ssim", "mouth_akd", "opening_corr", "faces_found")
                     else f"{mean(same, k):.2f}" for k in TABLED]
            lines.append(f"| {size} | {label} | {rate} | " + " | ".join(cells) +
                         f" | {mean(same, 'encode_fps'):.0f} / {mean(same, 'decode_fps'):.0f} |")
    return head + "\n".join(lines) + "\n"


def side_by_side(path: Path, fps: float, columns: list[tuple[str, list]]) -> None:
    """An mp4 of labelled columns (original | ours | baseline), one frame per input frame."""
    import cv2

    from facedeform.receiver.output import open_writer

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
