"""fd-experiment: our codec against H.264, H.265 and AV1 on the same face crops, over a bitrate ladder."""

import argparse
import os
import sys
from functools import lru_cache
from pathlib import Path

from common.cli import ArgumentParser, run_main

EPILOG = """examples:
  fd-experiment samples/grid_bbaf2n.mpg --out results/
  fd-experiment clips/*.mp4 --sizes 256 512 --qualities 1 3 5 --jobs 2
  fd-experiment clips/*.mp4 --scheduler tcp://10.0.0.5:8786   # a Dask cluster

Writes results.csv and results.json (one row per run), a plot per measure and
size (<measure>_<size>.png), and per clip and size a side-by-side video
(original | ours | x264 at the bitrate nearest ours).
"""


def parse_args(argv=None) -> argparse.Namespace:
    p = ArgumentParser(prog="fd-experiment", epilog=EPILOG, description=(
        "Bitrate against quality: each clip is cropped to the face, then coded by this codec over a "
        "ladder of quality levels and parameter sets, and by x264, x265 and SVT-AV1 over a ladder of "
        "bitrates; every decoded video is measured with the same tracker (AKD, mouth AKD, mouth-opening "
        "correlation, mouth-and-jaw motion error) and in pixels inside the face (PSNR, SSIM)."))
    p.add_argument("clips", nargs="+", type=Path, help="video files of talking faces")
    p.add_argument("--out", type=Path, default=Path("results"), help="output folder (default results/)")
    p.add_argument("--sizes", type=int, nargs="+", default=[256], choices=(128, 256, 512),
                   help="face-crop sizes (default 256)")
    p.add_argument("--qualities", type=int, nargs="+", default=[1, 2, 3, 4, 5], choices=range(1, 6),
                   metavar="Q", help="our quality levels (default 1 2 3 4 5)")
    p.add_argument("--layouts", nargs="+", default=["paper", "mouth", "full", "personal"],
                   choices=("paper", "full", "mouth", "personal"),
                   help="our parameter sets (default paper mouth full personal: mouth and personal are "
                        "fd-send's defaults without and with a motion basis); personal runs with the own "
                        "face only, its motion basis learned from the first half of the clip")
    p.add_argument("--faces", nargs="+", default=["generic", "own"], choices=("generic", "own"),
                   help="our receiver's face: the generic shaded one, and/or the speaker's own model made "
                        "by fd-enroll from the clip (default both)")
    p.add_argument("--send-every", type=int, nargs="+", default=[1], choices=range(1, 17), metavar="N",
                   help="our frame-rate divisors (fd-send --send-every: one frame in N is sent, the receiver "
                        "interpolates; default 1); runs with N > 1 are named ours-<layout>-every<N>")
    p.add_argument("--baselines", nargs="+", default=["x264", "x265", "av1"], choices=("x264", "x265", "av1"),
                   help="conventional codecs (default all three)")
    p.add_argument("--bitrates", type=float, nargs="+", default=[8, 12, 16, 24, 32, 48, 64, 96], metavar="KBPS",
                   help="baseline target bitrates in kbit/s (default 8 12 16 24 32 48 64 96)")
    p.add_argument("--seconds", type=float, help="use only the first SECONDS of each clip")
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="local worker processes (default: cores)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="run on a Dask cluster instead (needs dask.distributed)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    return run_main("fd-experiment", lambda: _run(args))


def _run(args) -> int:
    from experiment.clips import prepare
    from experiment.report import plot, write_rows

    args.out.mkdir(parents=True, exist_ok=True)
    work = args.out / "work"
    work.mkdir(exist_ok=True)
    say = (lambda line: None) if args.quiet else (lambda line: print(line, file=sys.stderr, flush=True))
    prepared = []
    for path in args.clips:
        for size in args.sizes:
            clip = prepare(path, size, work, args.seconds)
            say(f"fd-experiment: {clip.name} at {size}x{size}: {len(clip.frames)} frames at {clip.fps:g} fps")
            prepared.append({"name": clip.name, "path": str(clip.path), "fps": clip.fps})
    tasks = [{**c, "kind": "ours", "layout": layout, "quality": q, "own": face == "own", "every": n,
              "work": str(work)}
             for c in prepared for face in args.faces for layout in args.layouts for q in args.qualities
             for n in args.send_every if face == "own" or layout != "personal"]
    tasks += [{**c, "kind": codec, "bps": int(kbps * 1000)}
              for c in prepared for codec in args.baselines for kbps in args.bitrates]
    rows = []
    for row in _map(execute, tasks, args):
        rows.append(row)
        say(f"fd-experiment: [{len(rows)}/{len(tasks)}] {row['clip']} {row['size']} {row['codec']} "
            f"{row['setting']}: {row['bitrate_bps'] / 1000:.2f} kbit/s, AKD {row['akd_aligned']:.4f}, "
            f"mouth AKD {row['mouth_akd_aligned']:.4f}")
    rows.sort(key=lambda r: (r["clip"], r["size"], r["codec"], r["bitrate_bps"]))
    write_rows(rows, args.out)
    plots = plot(rows, args.out)
    for c in prepared:
        _side_by_side(_clip(c["name"], c["path"], c["fps"]), rows, args.out)
    say(f"fd-experiment: {len(rows)} runs -> {args.out}/results.csv, {len(plots)} plots")
    return 0


def _map(function, tasks: list, args):
    """Results in completion order, from a local process pool or a Dask cluster."""
    if args.scheduler:
        try:
            from dask.distributed import Client, as_completed
        except ImportError:
            from common.errors import FdError

            raise FdError("--scheduler needs dask.distributed: pip install 'facedeform[cluster]'") from None
        with Client(args.scheduler) as client:
            for future in as_completed(client.map(function, tasks, pure=False)):
                yield future.result()
        return
    if args.jobs <= 1:
        yield from map(function, tasks)
        return
    from concurrent.futures import ProcessPoolExecutor, as_completed

    with ProcessPoolExecutor(args.jobs) as pool:
        for future in as_completed([pool.submit(function, t) for t in tasks]):
            yield future.result()


@lru_cache(maxsize=2)
def _clip(name: str, path: str, fps: float):
    from experiment.clips import load

    return load(name, Path(path), fps)


def execute(task: dict) -> dict:
    """One run in a worker: loads the crop (cached per process) and codes and measures it."""
    from experiment.runs import run_baseline, run_ours

    clip = _clip(task["name"], task["path"], task["fps"])
    if task["kind"] == "ours":
        return run_ours(clip, task["quality"], task["layout"], Path(task["work"]), task["own"], task["every"])[0]
    return run_baseline(clip, task["kind"], task["bps"])[0]


def _side_by_side(clip, rows: list, out: Path) -> None:
    """original | ours (the middle-bitrate run, own face if run) | x264 at the bitrate nearest ours."""
    from experiment.report import side_by_side
    from experiment.runs import run_baseline, run_ours

    size = clip.frames[0].shape[0]
    same = [r for r in rows if r["clip"] == clip.name and r["size"] == size]
    mine = sorted((r for r in same if r["codec"].startswith("ours")), key=lambda r: r["bitrate_bps"])
    mine = [r for r in mine if r["codec"].endswith("-own")] or mine
    theirs = [r for r in same if r["codec"] == "x264"]
    if not mine or not theirs:
        return
    ours_row = mine[len(mine) // 2]
    near = min(theirs, key=lambda r: abs(r["bitrate_bps"] - ours_row["bitrate_bps"]))
    layout = ours_row["codec"].split("-")[1]
    _, ours = run_ours(clip, int(ours_row["setting"][1:]), layout, out / "work", ours_row["codec"].endswith("-own"))
    _, x264 = run_baseline(clip, "x264", int(near["setting"][:-3]))
    side_by_side(out / f"side_by_side_{clip.name}_{size}.mp4", clip.fps, [
        ("original", clip.frames),
        (f"ours {ours_row['bitrate_bps'] / 1000:.2f} kbit/s", ours),
        (f"x264 {near['bitrate_bps'] / 1000:.1f} kbit/s", x264)])


if __name__ == "__main__":
    sys.exit(main())
