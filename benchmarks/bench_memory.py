"""Peak memory of a long call: fd-send | fd-recv over 1, 10 and 60 minutes of input.

The sender is fd-send at its defaults reading the clip (the bundled one by
default) looped to the length asked for (sender.sources.LoopedSource), as fast
as the pipe takes it; the receiver is fd-recv at its defaults, its video thrown
away (-o - into /dev/null). Each length is a call of its own; the table gives
each process's peak resident set size (ru_maxrss): flat when memory does not
grow with the call.

    python benchmarks/bench_memory.py                 # 1 and 10 minutes
    python benchmarks/bench_memory.py --minutes 1 10 60
"""

import datetime
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from facedeform.common.cli import ArgumentParser, run_main

ROOT = Path(__file__).resolve().parents[1]
CLIP = ROOT / "samples" / "grid_bbaf2n.mpg"


def send(clip: str, seconds: float) -> None:
    """The sender process: fd-send's defaults on the looped clip, the stream on stdout."""
    from facedeform.sender.session import SendSession
    from facedeform.sender.sources import LoopedSource
    from facedeform.sender.transport import open_sink

    sink = open_sink("-")
    for packets in SendSession(LoopedSource(clip, seconds)).packets():
        sink.write(packets)
    sink.close()


def peak_rss_mb(pid: int) -> tuple[int, float]:
    """(exit status, peak resident set size in MB) of a child once it ends."""
    _, status, usage = os.wait4(pid, 0)
    return os.waitstatus_to_exitcode(status), usage.ru_maxrss / 1024  # Linux: kilobytes


def measure(clip: Path, minutes: float) -> tuple[int, float, float, float]:
    """(frames, fd-send MB, fd-recv MB, seconds taken) for ``minutes`` of input."""
    started = time.perf_counter()
    sender = subprocess.Popen([sys.executable, __file__, "--send", str(clip), str(60 * minutes)],
                              stdout=subprocess.PIPE, cwd=ROOT)
    receiver = subprocess.Popen([sys.executable, "-m", "facedeform.receiver.cli", "-", "-o", "-", "--json"],
                                stdin=sender.stdout, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=ROOT)
    sender.stdout.close()  # the receiver holds the pipe now
    send_code, send_mb = peak_rss_mb(sender.pid)
    err = receiver.stderr.read().decode()
    recv_code, recv_mb = peak_rss_mb(receiver.pid)
    if send_code or recv_code:
        sys.exit(f"bench_memory: fd-send exited {send_code}, fd-recv {recv_code}: {err.strip()}")
    frames = json.loads(err.strip().splitlines()[-1])["frames"]
    return frames, send_mb, recv_mb, time.perf_counter() - started


def main() -> None:
    p = ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("clip", nargs="?", type=Path, default=CLIP)
    p.add_argument("--minutes", type=float, nargs="*", default=[1.0, 10.0], help="input lengths (default 1 10)")
    if sys.argv[1:2] == ["--send"]:
        send(sys.argv[2], float(sys.argv[3]))
        return
    args = p.parse_args()
    print(f"{datetime.date.today()}, {args.clip.name} looped, fd-send | fd-recv at their defaults; peak RSS")
    print("| minutes of input | frames | fd-send peak RSS (MB) | fd-recv peak RSS (MB) | wall time (s) |")
    print("|---|---|---|---|---|")
    for minutes in args.minutes:
        frames, send_mb, recv_mb, seconds = measure(args.clip, minutes)
        print(f"| {minutes:g} | {frames} | {send_mb:.0f} | {recv_mb:.0f} | {seconds:.0f} |", flush=True)


if __name__ == "__main__":
    raise SystemExit(run_main("bench_memory.py", lambda: main() or 0))
