"""Glass-to-glass latency of a live call over loopback UDP, at fd-send's defaults.

A receiver process listens on udp://127.0.0.1:PORT and renders every frame as
``fd-recv --listen`` does (its frames go nowhere: no video writer); then a sender
process reads the clip (the bundled one by default, looped) in real time
(sender.sources.PacedSource, as ``fd-send --realtime``) and sends it there as
fd-send does. Per frame, the latency runs
from the moment the paced source hands the frame to the sender to the moment the
receiver's rendered frame is ready for its sinks (both sides read the same
monotonic clock). Prints one Markdown table row per setting: median, 95th
percentile and maximum latency, the delay before the first frame, and the median
over the frames after the sender's first second (which it holds to find the rest
face and the coding basis before the header goes out). A short call first, not
measured, fills the compiled kernels' disk cache as on a machine that has made a
call before (--cold leaves it out; with an empty NUMBA_CACHE_DIR it is a first call
after installation).

    python benchmarks/bench_latency.py                       # 20 s of input, fd-send's defaults
    python benchmarks/bench_latency.py --seconds 60 --frames-per-packet 1 2 4
"""

import datetime
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from facedeform.common.cli import ArgumentParser, run_main
from facedeform.sender.session import first_second
from facedeform.sender.sources import open_source

ROOT = Path(__file__).resolve().parents[1]
CLIP = ROOT / "samples" / "grid_bbaf2n.mpg"


class Stamped:
    """A source that notes when each frame is handed over (``time.monotonic()``)."""

    def __init__(self, source) -> None:
        self._source = source
        self.fps, self.size, self.length = source.fps, source.size, source.length
        self.times: list[float] = []

    def frames(self):
        for frame in self._source.frames():
            self.times.append(time.monotonic())
            yield frame


class Recorder:
    """A receiver sink that notes when each rendered frame is ready."""

    def __init__(self) -> None:
        self.times: list[float] = []

    def write(self, rgb: np.ndarray) -> None:
        self.times.append(time.monotonic())

    def close(self) -> None:
        pass


def send(clip: str, seconds: float, port: int, frames_per_packet: int, times_path: str) -> None:
    """The sender process: the clip looped to ``seconds`` and paced, sent as fd-send -o udp:// sends."""
    from facedeform.sender.config import SendConfig
    from facedeform.sender.session import SendSession
    from facedeform.sender.sources import LoopedSource, PacedSource
    from facedeform.sender.transport import open_sink

    source = Stamped(PacedSource(LoopedSource(clip, seconds)))
    session = SendSession(source, SendConfig(frames_per_packet=frames_per_packet, datagrams=True))  # as -o udp://
    sink = open_sink(f"udp://127.0.0.1:{port}")
    for packets in session.packets():
        sink.write(packets)
    sink.close()
    np.save(times_path, np.array(source.times))


def receive(times_path: str, warm: bool) -> None:
    """The receiver process: prints the port it listens on, then renders the call as fd-recv does;
    ``warm``: first draws a face once, loading the renderer's compiled kernels before the call
    (which fd-recv does once the header arrives)."""
    from facedeform.codec.model.face_model import load_base_face
    from facedeform.common.parameters import LAYOUTS
    from facedeform.protocol.stream import Header, steps_for
    from facedeform.receiver.face_view import open_view
    from facedeform.receiver.session import ReceiveSession
    from facedeform.receiver.transport import Listener

    if warm:
        face, names = load_base_face(), LAYOUTS["mouth"]
        view = open_view("shaded", Header(25.0, names, steps_for(names), face.content_id), face, (64, 64))
        view.render(np.zeros(len(names)))
    listener = Listener("udp://127.0.0.1:0", idle=5.0)
    print(listener.url.rsplit(":", 1)[1], flush=True)
    recorder = Recorder()
    session = ReceiveSession(lambda fps, size: [recorder], None)
    session.run(listener.source())
    session.close()
    np.save(times_path, np.array(recorder.times))


def measure(clip: Path, seconds: float, frames_per_packet: int, warm: bool = False) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        shown_path, sent_path = str(Path(tmp) / "shown.npy"), str(Path(tmp) / "sent.npy")
        receiver = subprocess.Popen([sys.executable, __file__, "--receive", shown_path, str(int(warm))],
                                    stdout=subprocess.PIPE, cwd=ROOT)
        port = receiver.stdout.readline().decode().strip()
        sender = subprocess.Popen([sys.executable, __file__, "--send", str(clip), str(seconds), port,
                                   str(frames_per_packet), sent_path], cwd=ROOT)
        if sender.wait() or receiver.wait():
            sys.exit("bench_latency: the sender or the receiver failed")
        shown, available = np.load(shown_path), np.load(sent_path)
    if len(shown) != len(available):
        sys.exit(f"bench_latency: {len(available)} frames sent, {len(shown)} rendered")
    ms = 1000 * (shown - available)
    held = first_second(open_source(str(clip)).fps)  # frames the sender holds
    return {"frames": len(ms), "median": np.median(ms), "p95": np.percentile(ms, 95), "max": ms.max(),
            "first": ms[0], "after_first_second": np.median(ms[held:]), "p95_after": np.percentile(ms[held:], 95)}


def main() -> None:
    p = ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("clip", nargs="?", type=Path, default=CLIP)
    p.add_argument("--seconds", type=float, default=20.0, help="input played in real time (default 20)")
    p.add_argument("--frames-per-packet", type=int, nargs="*", default=[2], help="fd-send's option (default 2)")
    p.add_argument("--cold", action="store_true", help="no warm-up call first")
    p.add_argument("--warm-receiver", action="store_true",
                   help="also measure a receiver that loads its renderer before the call instead of at its header")
    if sys.argv[1:2] == ["--send"]:
        clip, seconds, port, fpp, times_path = sys.argv[2:]
        send(clip, float(seconds), int(port), int(fpp), times_path)
        return
    if sys.argv[1:2] == ["--receive"]:
        receive(sys.argv[2], sys.argv[3] == "1")
        return
    args = p.parse_args()
    print(f"{datetime.date.today()}, {args.clip.name} looped to {args.seconds:g} s in real time, loopback UDP, "
          "latency in ms from the frame's arrival at the sender to its rendered frame at the receiver; "
          f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} before")
    print("| frames per packet | frames | median | 95th percentile | max | first frame | "
          "median after the first second | 95th percentile after it |")
    print("|---|---|---|---|---|---|---|---|")
    if not args.cold:
        measure(args.clip, 2.0, 2)
    settings = [(fpp, warm) for fpp in args.frames_per_packet for warm in (False, True)[:1 + args.warm_receiver]]
    for fpp, warm in settings:
        r = measure(args.clip, args.seconds, fpp, warm)
        print(f"| {fpp}{', receiver warmed' if warm else ''} | {r['frames']} | {r['median']:.1f} | {r['p95']:.1f} | "
              f"{r['max']:.1f} | {r['first']:.0f} | {r['after_first_second']:.1f} | {r['p95_after']:.1f} |",
              flush=True)


if __name__ == "__main__":
    raise SystemExit(run_main("bench_latency.py", lambda: main() or 0))
