"""fd-experiment: our codec against H.264, H.265, AV1 and H.266 on the same face crops, judged on the whole picture."""

import argparse
import json
import os
import sys
from functools import lru_cache
from pathlib import Path

from facedeform.common.cli import ArgumentParser, number, run_main

EPILOG = """examples:
  fd-experiment samples/grid_bbaf2n.mpg --out results/
  fd-experiment clips/*.mp4 --sizes 256 512 --qualities 1 3 5 --jobs 2
  fd-experiment clips/*.mp4 --scheduler tcp://10.0.0.5:8786   # a Dask cluster sharing --out

Writes one file per run in <out>/rows/ as it finishes (run again with the same
--out to resume: finished runs are not redone), then results.csv and
results.json (one row per run; ours with the rate of its costliest 2 seconds,
costliest_2s_bps, which fd-send keeps within 10 % of --bitrate), table.md (ours at fd-send's default level if
run, else at our lowest rate, against each baseline at its floor and at about
3 times it), a plot per measure and size
(<measure>_<size>.png, overview_<size>.png) and per clip and size a
side-by-side video (original | ours | x264 at the rate nearest ours | SVT-AV1
at its floor). Coded streams, crops and face models stay in <out>/work/.
"""


def parse_args(argv=None) -> argparse.Namespace:
    from facedeform.experiment.baselines import CODECS
    from facedeform.sender.config import QUALITY_RATES

    p = ArgumentParser(prog="fd-experiment", epilog=EPILOG, description=(
        "Bitrate against quality: each clip is cut to one square face crop per size, written losslessly "
        "once; every codec takes that crop: this codec over its qualities (fd-enroll, fd-send, fd-recv), "
        "and x264, x265, SVT-AV1 and VVenC from their floor (coarsest quantiser) up. Every decoded video is "
        "measured whole against the crop (PSNR of R, G, B and its 5th percentile over frames, SSIM and "
        "MS-SSIM on luma, VMAF) and with the same tracker (AKD, mouth AKD, mouth-opening correlation, "
        "mouth-and-jaw motion error)."))
    p.add_argument("clips", nargs="+", type=Path, help="video files of talking faces")
    p.add_argument("--out", type=Path, default=Path("results"), help="output folder (default results/)")
    p.add_argument("--sizes", type=int, nargs="+", default=[256, 512], choices=(128, 256, 512),
                   help="face-crop sizes (default 256 512)")
    p.add_argument("--qualities", type=int, nargs="*", default=[1, 2, 3, 4, 5], choices=range(1, 6),
                   metavar="Q", help="our runs at fd-send --quality Q, the rates " + ", ".join(
                       f"{r / 1000:g}" for r in QUALITY_RATES.values()) + " kbit/s (default all five; none: only "
                       "--bitrates and --levels)")
    p.add_argument("--levels", type=int, nargs="*", default=[], choices=range(1, 6), metavar="L",
                   help="also our runs at fd-send --level L, the parameters' quantiser level without a rate "
                        "(fd-send's default is 3)")
    p.add_argument("--bitrates", type=number(0.5, 1000), nargs="*", default=[], metavar="KBPS",
                   help="also our runs at these rates (fd-send --bitrate: with the own face, what the parameters "
                        "leave carries the picture layer), e.g. 1.5 4 10 30")
    p.add_argument("--layouts", nargs="+", default=["auto"], choices=("auto", "paper", "full", "mouth", "personal"),
                   help="our parameter sets (default auto: fd-send's default, personal with the own face's "
                        "motion basis); personal runs with the own face only")
    p.add_argument("--faces", nargs="*", default=["own"], choices=("generic", "own"),
                   help="our receiver's face: the speaker's own model made by fd-enroll from the crop (default; "
                        "the receiver draws the whole picture from it when it can), and/or the generic shaded "
                        "one; none: baselines only")
    p.add_argument("--send-every", type=int, nargs="+", default=[1], choices=range(1, 17), metavar="N",
                   help="our frame-rate divisors (fd-send --send-every: one frame in N is sent, the receiver "
                        "interpolates; default 1); runs with N > 1 are named ours-<layout>-every<N>")
    p.add_argument("--baselines", nargs="*", default=list(CODECS), choices=tuple(CODECS),
                   help=f"conventional codecs (default all: {' '.join(CODECS)}; vvc is VVenC; none: ours only)")
    p.add_argument("--rungs", type=number(1, 20, kind=int), default=5, metavar="N",
                   help="baseline settings per codec, from its floor (CRF or QP at its coarsest) up by 3 "
                        "quantiser steps each, 6 for vvc (default 5)")
    p.add_argument("--seconds", type=number(0.1, 36000), help="use only the first SECONDS of each clip")
    p.add_argument("--jobs", type=number(1, 256, kind=int), default=os.cpu_count() or 1,
                   help="local worker processes, 1-256 (default: cores)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on a Dask cluster instead (needs dask.distributed; workers must see --out)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    return run_main("fd-experiment", lambda: _run(args))


def _run(args) -> int:
    from facedeform.common.errors import InputError
    from facedeform.experiment.baselines import CODECS, check, ladder
    from facedeform.experiment.clips import prepare
    from facedeform.experiment.metrics import vmaf_available
    from facedeform.experiment.report import bd_table, plot, table, write_rows
    from facedeform.experiment.runs import ours_name
    from facedeform.sender.config import QUALITY_RATES

    if not (args.faces or args.baselines):
        raise InputError("nothing to run: give --faces or --baselines")
    if args.rungs < 1:
        raise InputError(f"--rungs must be at least 1, not {args.rungs}")
    for codec in args.baselines:
        check(codec)
    vmaf_available()
    work, done = args.out / "work", args.out / "rows"
    try:
        work.mkdir(parents=True, exist_ok=True)
        done.mkdir(exist_ok=True)
    except OSError as exc:
        raise InputError(f"--out {args.out}: cannot make the folder ({exc.strerror or exc})") from None
    say = (lambda line: None) if args.quiet else (lambda line: print(line, file=sys.stderr, flush=True))
    prepared = []
    for path in args.clips:
        for size in args.sizes:
            clip = prepare(path, size, work, args.seconds)
            say(f"fd-experiment: {clip.name} at {size}x{size}: {len(clip.frames)} frames at {clip.fps:g} fps")
            prepared.append({"name": clip.name, "path": str(clip.path), "fps": clip.fps, "size": size})
    rates = [QUALITY_RATES[q] / 1000 for q in args.qualities] + args.bitrates
    settings = [f"l{level}" for level in args.levels] + [f"{b:g}k" for b in dict.fromkeys(rates)]
    tasks = [{**c, "kind": "ours", "layout": layout, "setting": s, "own": face == "own", "every": n,
              "work": str(work), "key": f"{ours_name(layout, face == 'own', n)}_{s}"}
             for c in prepared for face in args.faces for layout in args.layouts for s in settings
             for n in args.send_every if face == "own" or layout != "personal"]
    tasks += [{**c, "kind": codec, "setting": s, "work": str(work), "key": f"{codec}_{CODECS[codec].knob}{s}"}
              for c in prepared for codec in args.baselines for s in ladder(codec, args.rungs)]

    def row_file(task: dict) -> Path:
        return done / f"{task['name']}_{task['size']}_{task['key']}.json"

    todo = [t for t in tasks if not row_file(t).exists()]
    if len(todo) < len(tasks):
        say(f"fd-experiment: {len(tasks) - len(todo)} of {len(tasks)} runs already done in {done}")
    for count, (task, row) in enumerate(_map(execute, todo, args), 1):
        partial = row_file(task).with_suffix(".part")
        partial.write_text(json.dumps(row, default=float) + "\n")
        partial.replace(row_file(task))  # whole or absent: a crash never leaves half a row
        say(f"fd-experiment: [{count}/{len(todo)}] {row['clip']} {row['size']} {row['codec']} {row['setting']}: "
            f"{row['bitrate_bps'] / 1000:.2f} kbit/s, PSNR {row['psnr']:.2f} dB, VMAF {row['vmaf']:.1f}, "
            f"mouth AKD {row['mouth_akd']:.4f}"
            + (f", costliest 2 s {row['costliest_2s_bps'] / 1000:.2f} kbit/s" if "costliest_2s_bps" in row else ""))
    rows = sorted((json.loads(row_file(t).read_text()) for t in tasks),
                  key=lambda r: (r["clip"], r["size"], r["codec"], r["bitrate_bps"]))
    write_rows(rows, args.out)
    (args.out / "table.md").write_text(table(rows) + "\nBD-rate of ours against each baseline (negative: fewer bits "
                                       "for the same quality), where the mean curves overlap:\n\n" + bd_table(rows))
    plots = plot(rows, args.out)
    for c in prepared:
        _side_by_side(c, rows, args.out)
    say(f"fd-experiment: {len(rows)} runs -> {args.out}/results.csv, {len(plots)} plots")
    return 0


def _map(function, tasks: list, args):
    """(task, result) pairs in completion order, from a local process pool or a Dask cluster."""
    if not tasks:
        return
    if args.scheduler:
        try:
            from dask.distributed import Client, as_completed
        except ImportError:
            from facedeform.common.errors import FdError

            raise FdError("--scheduler needs dask.distributed: pip install 'facedeform[cluster]'") from None
        with Client(args.scheduler) as client:
            futures = client.map(function, tasks, pure=False)
            index = {future.key: task for future, task in zip(futures, tasks)}
            for future in as_completed(futures):
                yield index[future.key], future.result()
        return
    if args.jobs <= 1:
        for task in tasks:
            yield task, function(task)
        return
    from concurrent import futures

    with futures.ProcessPoolExecutor(args.jobs) as pool:
        pending = {pool.submit(function, t): t for t in tasks}
        try:
            for future in futures.as_completed(pending):
                yield pending[future], future.result()
        finally:  # a failed run ends the whole at once (finished rows are kept), not after every other run
            pool.shutdown(cancel_futures=True)


@lru_cache(maxsize=2)
def _clip(name: str, path: str, fps: float):
    from facedeform.experiment.clips import load

    return load(name, Path(path), fps)


def execute(task: dict) -> dict:
    """One run in a worker: loads the crop (cached per process) and codes and measures it."""
    from facedeform.experiment.runs import run_baseline, run_ours

    clip = _clip(task["name"], task["path"], task["fps"])
    if task["kind"] == "ours":
        return run_ours(clip, task["setting"], task["layout"], Path(task["work"]), task["own"], task["every"])[0]
    return run_baseline(clip, task["kind"], task["setting"], Path(task["work"]))[0]


def _side_by_side(clip: dict, rows: list, out: Path) -> None:
    """original | ours (fd-send's default level if run, else our lowest rate; own face if run) | x264 at
    the rate nearest ours (one-off bytes counted) | SVT-AV1 at its floor, from the streams the runs left
    in the work folder."""
    from facedeform.experiment.baselines import CODECS, decode
    from facedeform.experiment.clips import read_video
    from facedeform.experiment.report import headline, side_by_side
    from facedeform.experiment.runs import receive

    size, work = clip["size"], out / "work"
    same = [r for r in rows if r["clip"] == clip["name"] and r["size"] == size]
    columns = [("original", read_video(Path(clip["path"])))]
    mine = sorted((r for r in same if r["codec"].startswith("ours")), key=lambda r: r["bitrate_bps"])
    mine = [r for r in mine if "-own" in r["codec"]] or mine
    if mine:
        setting = headline(mine)
        ours = next(r for r in mine if r["setting"] == setting)
        face = [str(work / f"{clip['name']}_{size}.fdface")] if "-own" in ours["codec"] else []
        frames = receive(work / f"{clip['name']}_{size}_{ours['codec']}_{ours['setting']}.fd", size, face)
        columns.append((f"ours {ours['bitrate_bps'] / 1000:.2f} kbit/s, {ours['bitrate_oneoff_bps'] / 1000:.1f} "
                        "with one-off", frames))
    for codec, label in (("x264", "x264"), ("av1", "SVT-AV1 floor")):
        theirs = [r for r in same if r["codec"] == codec]
        if not theirs:
            continue
        pick = (min(theirs, key=lambda r: abs(r["bitrate_bps"] - ours["bitrate_oneoff_bps"])) if codec == "x264"
                and mine else min(theirs, key=lambda r: r["bitrate_bps"]))
        stream = work / f"{clip['name']}_{size}_{codec}_{pick['setting']}.{CODECS[codec].suffix}"
        columns.append((f"{label} {pick['bitrate_bps'] / 1000:.1f} kbit/s", decode(codec, stream, (size, size))))
    if len(columns) > 1:
        side_by_side(out / f"side_by_side_{clip['name']}_{size}.mp4", clip["fps"], columns)


if __name__ == "__main__":
    sys.exit(main())
