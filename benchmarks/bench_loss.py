"""Frames that survive a lossy datagram link, what redundancy and late join cost, and where a junk flood breaks.

``loss``: on fd-send dumps (``fd-send CLIP -o /dev/null --dump DUMP.npz``), the stream
as fd-send codes it (2 frames per packet, the first second's basis, a keyframe a second) is cut
into datagrams by ``protocol.encoder.Datagrams`` with 0-3 earlier packets carried again, frames
datagrams are dropped at random (0, 1, 5, 10, 20 %) or in bursts of 3, and a ``DatagramDecoder``
decodes what is left. Prints, per redundancy, the bits per frame (header excluded) and the good
frames (decoded, not concealed) in % of all, mean over the clips and 5 seeds; depth 0 is the
stream without copies.

``bursts``: fd-send's stream over udp:// (a frame a datagram, three packets carried again, a
keyframe every 0.24 s; ``--frames-per-packet``, ``--copies`` and ``--key-interval`` change them)
under the loss patterns of a real link, in process (not paced over a socket): random loss, fixed
bursts of 2, 3 and 8 datagrams, and Gilbert-Elliott loss (a good state that loses nothing and a
bad one that loses everything, bursts of 3 on average), each also with 5 % of neighbouring datagrams swapped and 2 %
duplicated. Prints the good frames in % and the longest freeze (frames in a row not good),
mean and worst over the clips and seeds.

``udp``: the same patterns (datagrams also reordered and duplicated) over real loopback UDP to
``fd-recv --listen``, sent as fast as a live call sends them; fd-recv's ``--dump`` says which frames
it drew from data. A call's length per clip and seed and pattern (``--seeds``, 5 by default).

``layer``: the whole picture with its picture layer over datagrams, on videos (each with its face
file beside it, ``CLIP.fdface`` as fd-experiment leaves it, or enrolled from the clip): fd-send's
session at ``--bitrates`` (kbit/s; without the receiver's reports, so a picture key a second), its
datagrams lost in three of the patterns below (each also reordered and duplicated) and decoded in
process by the library's receiver. Prints per pattern the mean PSNR of the drawn frames against the
clip's, its 5th percentile, what the loss took from the loss-free call's PSNR, and the frames drawn
more than 1 dB under the loss-free call's (the layer lost until its next key), mean over clips and seeds.

``header``: bits per frame that repeating the header before every Nth keyframe costs, for
each layout's dump (``DUMP.npz``, ``DUMP.paper.npz``, ``DUMP.full.npz``).

``flood``: a sealed stream over loopback UDP to ``fd-recv --listen`` at 25 packets a second with
junk datagrams at rising rates; prints the real frames delivered at each rate.
"""

import json
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from facedeform.codec.model.face_model import load_base_face
from facedeform.common.cli import ArgumentParser, run_main
from facedeform.protocol.encoder import COPIES, Datagrams
from facedeform.protocol.stream import DatagramDecoder, Frame, PacketEncoder
from facedeform.sender.config import DATAGRAM_FRAMES
from facedeform.sender.session import DATAGRAM_KEYS, first_basis, read_dump, stream_header

ROOT = Path(__file__).resolve().parents[1]
LOSSES = (0.0, 0.01, 0.05, 0.10, 0.20)


def datagrams(path: Path, copies: int, header_every: int = 0, eager: int = 0, keys: float = 1.0,
              key_interval: int | None = None, per_packet: int = 2) -> tuple[list[bytes], int, int]:
    """(datagrams, header packet bytes, frames) of fd-send's stream of a dump, the header sent once
    unless asked; a keyframe every ``keys`` seconds or ``key_interval`` frames."""
    names, fps, params, found = read_dump(path)
    basis = first_basis(names, fps, list(zip(params, found)))
    header = stream_header(names, fps, load_base_face().content_id, basis=basis, keys=keys)
    if key_interval is not None:
        header = replace(header, key_interval=key_interval)
    enc = PacketEncoder(header, per_packet)
    head = enc.header()
    pack = Datagrams(head[0], copies, header_every, eager)
    out = pack.add(head)
    for x, seen in zip(params, found):
        out += pack.add(enc.frame(x, seen))
    return out + pack.add(enc.end()), len(head[0]), len(params)


def lose(count: int, rate: float, burst: int, rng: np.random.Generator) -> np.ndarray:
    """(count,) bool: which datagrams are lost; bursts of ``burst`` start at ``rate / burst``."""
    starts = np.flatnonzero(rng.random(count) < rate / burst)
    lost = np.zeros(count, bool)
    for s in starts:
        lost[s:s + burst] = True
    return lost


def lose_gilbert_elliott(count: int, rate: float, burst: float, rng: np.random.Generator) -> np.ndarray:
    """(count,) bool: Gilbert-Elliott loss, a fraction ``rate`` of datagrams in bursts of ``burst`` on average."""
    to_bad, to_good = rate / (burst * (1.0 - rate)), 1.0 / burst
    lost, bad = np.zeros(count, bool), False
    for i, u in enumerate(rng.random(count)):
        bad = u >= to_good if bad else u < to_bad
        lost[i] = bad
    return lost


def shuffled(stream: list[bytes], rng: np.random.Generator, swap: float, duplicate: float) -> list[bytes]:
    """``stream`` with neighbours swapped (probability ``swap`` each) and datagrams sent twice (``duplicate``)."""
    out = list(stream)
    for i in range(len(out) - 1):
        if rng.random() < swap:
            out[i], out[i + 1] = out[i + 1], out[i]
    return [d for d in out for _ in range(2 if rng.random() < duplicate else 1)]


def arriving(stream: list[bytes], lost: np.ndarray, rng: np.random.Generator | None = None,
             swap: float = 0.0, duplicate: float = 0.0) -> list[bytes]:
    """The datagrams that arrive when the body datagrams ``lost`` are dropped (never the header or
    the end mark, sent twice) and the rest ``shuffled`` if ``rng`` is given."""
    body = [i for i in range(len(stream)) if i and i < len(stream) - 2]
    dropped = {body[i] for i in np.flatnonzero(lost[:len(body)])}
    kept = [d for i, d in enumerate(stream) if i not in dropped]
    return kept if rng is None else kept[:1] + shuffled(kept[1:], rng, swap, duplicate)


def frames_good(stream: list[bytes], lost: np.ndarray, frames: int, rng: np.random.Generator | None = None,
                swap: float = 0.0, duplicate: float = 0.0) -> np.ndarray:
    """(frames,) bool: which frames the receiver drew from data (not concealed, not missing) when
    the body datagrams ``lost`` are dropped and the rest arrive ``shuffled``."""
    dec, good = DatagramDecoder(), np.zeros(frames, bool)
    for d in arriving(stream, lost, rng, swap, duplicate):
        for e in dec.receive(d):
            if isinstance(e, Frame) and e.seq < frames:
                good[e.seq] = not e.concealed
    return good


def longest_freeze(good: np.ndarray) -> int:
    runs, longest = 0, 0
    for g in good:
        runs = 0 if g else runs + 1
        longest = max(longest, runs)
    return longest


#: The lossy-link issue's patterns: (label, share of datagrams lost, "fixed" bursts or Gilbert-Elliott "ge",
#: burst length).
PATTERNS = [("random 5 %", 0.05, "fixed", 1), ("random 10 %", 0.10, "fixed", 1),
            ("random 20 %", 0.20, "fixed", 1), ("bursts of 2, 5 %", 0.05, "fixed", 2),
            ("bursts of 3, 5 %", 0.05, "fixed", 3),
            ("bursts of 8, 5 %", 0.05, "fixed", 8), ("Gilbert-Elliott 5 %, bursts of 3", 0.05, "ge", 3),
            ("Gilbert-Elliott 10 %, bursts of 3", 0.10, "ge", 3)]


def pattern_loss(count: int, rate: float, kind: str, burst: int, rng: np.random.Generator) -> np.ndarray:
    return lose(count, rate, burst, rng) if kind == "fixed" else lose_gilbert_elliott(count, rate, burst, rng)


def bench_bursts(dumps: list[Path], seeds: int, key_interval: int | None = None, copies: int = COPIES,
                 per_packet: int = DATAGRAM_FRAMES) -> None:
    streams = [datagrams(path, copies, keys=DATAGRAM_KEYS, key_interval=key_interval, per_packet=per_packet)
               for path in dumps]
    bits = np.mean([8 * (sum(map(len, stream)) - head) / n for stream, head, n in streams])
    print(f"{bits:.1f} bits a frame, header excluded, a keyframe every {key_interval or f'{DATAGRAM_KEYS:g} s'}, "
          f"{copies} copies, {per_packet} frames a packet\n")
    print("| pattern | good frames % | + reordered, duplicated | longest freeze, mean (worst) "
          "| + reordered, duplicated |")
    print("|---|---|---|---|---|")
    for label, rate, kind, burst in PATTERNS:
        good: dict[bool, list[float]] = {False: [], True: []}
        freeze: dict[bool, list[int]] = {False: [], True: []}
        for stream, _, n in streams:
            for seed in range(seeds):
                rng = np.random.default_rng(seed)
                lost = pattern_loss(len(stream), rate, kind, burst, rng)
                for mixed in (False, True):
                    g = frames_good(stream, lost, n, np.random.default_rng(seed + 1000) if mixed else None,
                                    0.05, 0.02)
                    good[mixed].append(100 * g.mean())
                    freeze[mixed].append(longest_freeze(g))
        print(f"| {label} | {np.mean(good[False]):.1f} | {np.mean(good[True]):.1f} | {np.mean(freeze[False]):.1f} "
              f"({max(freeze[False])}) | {np.mean(freeze[True]):.1f} ({max(freeze[True])}) |", flush=True)


def received_over_udp(kept: list[bytes], frames: int, seconds: float, tmp: Path) -> np.ndarray:
    """(frames,) bool: the frames ``fd-recv --listen udp://`` drew from data when the datagrams ``kept``
    reach it over loopback, sent evenly over ``seconds`` as a live call sends them."""
    dump = tmp / "recv.npz"
    proc = subprocess.Popen([sys.executable, "-m", "facedeform.receiver.cli", "--listen", "udp://127.0.0.1:0",
                             "-o", str(tmp / "out.y4m"), "--size", "64", "--dump", str(dump), "--timeout", "3"],
                            stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, cwd=ROOT, bufsize=0)
    port = int(proc.stderr.readline().decode().rsplit(":", 1)[1])
    gap, start = seconds / len(kept), time.perf_counter()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for i, d in enumerate(kept):
            time.sleep(max(0.0, start + i * gap - time.perf_counter()))
            sock.sendto(d, ("127.0.0.1", port))
    err = proc.communicate(timeout=120)[1].decode()
    if proc.returncode:
        raise SystemExit(f"fd-recv failed: {err.strip().splitlines()[-1:]}")
    good = np.zeros(frames, bool)
    with np.load(dump) as d:
        seq, concealed = d["seq"], d["concealed"]
    inside = seq < frames
    good[seq[inside]] = ~concealed[inside]
    return good


def bench_udp(dumps: list[Path], seeds: int) -> None:
    """The bursts patterns, datagrams reordered and duplicated as in ``bursts``, sent over loopback UDP
    to fd-recv paced as a live call; its --dump says which frames it drew from data."""
    streams = [datagrams(path, COPIES, keys=DATAGRAM_KEYS, per_packet=DATAGRAM_FRAMES) for path in dumps]
    fps = [read_dump(path)[1] for path in dumps]
    print("| pattern | good frames % | longest freeze, mean (worst) |")
    print("|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for label, rate, kind, burst in PATTERNS:
            good, freeze = [], []
            for (stream, _, n), rate_fps in zip(streams, fps):
                for seed in range(seeds):
                    rng = np.random.default_rng(seed)
                    kept = arriving(stream, pattern_loss(len(stream), rate, kind, burst, rng),
                                    np.random.default_rng(seed + 1000), 0.05, 0.02)
                    g = received_over_udp(kept, n, n / rate_fps, Path(tmp))
                    good.append(100 * g.mean())
                    freeze.append(longest_freeze(g))
            print(f"| {label} | {np.mean(good):.1f} | {np.mean(freeze):.1f} ({max(freeze)}) |", flush=True)


#: The patterns ``layer`` runs (a whole picture's call is slower to decode than the parameters alone).
LAYER_PATTERNS = [("no loss", 0.0, "fixed", 1), ("random 5 %", 0.05, "fixed", 1),
                  ("bursts of 3, 5 %", 0.05, "fixed", 3), ("Gilbert-Elliott 10 %, bursts of 3", 0.10, "ge", 3)]


def layer_subject(clip: Path) -> tuple[object, list[np.ndarray]]:
    """(face, RGB frames) of ``clip``: its face file beside it (``CLIP.fdface``), else enrolled from it."""
    import facedeform
    from facedeform.experiment.clips import read_video

    path = clip.with_suffix(".fdface")
    return facedeform.Face.load(str(path)) if path.exists() else facedeform.enroll(str(clip)), read_video(clip)


def layer_session(clip: Path, face, kbps: float):
    """fd-send's session of the whole picture of ``clip`` at ``kbps`` over datagrams, the picture layer on."""
    from facedeform.sender.config import SendConfig
    from facedeform.sender.session import SendSession

    return SendSession(str(clip), SendConfig(bitrate=1000 * kbps, embed_face=False, datagrams=True), face=face,
                       warn=lambda line: None)


class DrawingReceiver:
    """The library's receiver in process (its session and the library decoder's sink): what it draws of
    each frame, by frame number (its k-th picture is of the k-th frame decoded: it draws them in order,
    some once the picture layer's next video frame has come)."""

    def __init__(self, face, counts=None) -> None:
        from facedeform.api import _Collect
        from facedeform.receiver.session import ReceiveSession

        self._images: list[np.ndarray] = []
        self._session = ReceiveSession(lambda fps, size: [_Collect(self._images)], None, face.model,
                                       warn=lambda line: None)
        if counts is not None:  # the picture layer's losses go where the reports read them, as fd-recv's
            self._session.counts = counts
        self._seqs: list[int] = []

    def handle(self, events: list) -> None:
        self._seqs += [e.seq for e in events if isinstance(e, Frame)]
        self._session.handle(events, time.perf_counter())

    def frames(self, count: int) -> list[np.ndarray | None]:
        """The frames drawn of the first ``count`` (None: a frame never drawn), the call having ended."""
        self._session.close()
        drawn = dict(zip(self._seqs, self._images))
        return [drawn.get(seq) for seq in range(count)]


def drawn_frames(kept: list[bytes], face, count: int) -> list[np.ndarray | None]:
    """What the library's receiver draws of each of ``count`` frames from the datagrams ``kept``, in
    order (None: a frame it never drew)."""
    receiver, decoder = DrawingReceiver(face), DatagramDecoder()
    for datagram in kept:
        receiver.handle(decoder.receive(datagram))
    return receiver.frames(count)


def reported_call(clip: Path, face, kbps: float, lost: np.ndarray) -> list[np.ndarray | None]:
    """What the library's receiver draws of fd-send's whole picture of ``clip`` at ``kbps`` over datagrams
    whose body datagrams ``lost`` (in order, cycled; the header's never) are dropped, the receiver
    reporting to the sender as fd-recv does (experiment/reporting.py)."""
    from facedeform.experiment.reporting import ReportingReceiver

    session = layer_session(clip, face, kbps)
    link = ReportingReceiver(session, session.header.fps)
    receiver = DrawingReceiver(face, link.decoder.stats)
    for i, datagram in enumerate(d for datagrams in session.packets() for d in datagrams):
        if not i or not lost[(i - 1) % len(lost)]:
            receiver.handle(link.receive(datagram))
    return receiver.frames(session.frame_count)


def shown_psnr(drawn: list[np.ndarray | None], frames: list[np.ndarray]) -> np.ndarray:
    """Per-frame PSNR (experiment.metrics.psnr_rgb, as fd-experiment's) of what a receiver shows: a frame
    never drawn shows the one before it (the first: black)."""
    from facedeform.experiment.metrics import psnr_rgb

    shown, last = [], np.zeros_like(frames[0])
    for image in drawn:
        last = last if image is None else image
        shown.append(last)
    return psnr_rgb(frames, shown)


def bench_layer(clips: list[Path], bitrates: list[float], seeds: int, reports: bool = False) -> None:
    subjects = [(clip, *layer_subject(clip)) for clip in clips]
    print("| kbit/s | pattern | PSNR dB | 5th percentile | loss's cost, dB | frames > 1 dB under the loss-free call |")
    print("|---|---|---|---|---|---|")
    for kbps in bitrates:
        # without reports the sender cannot hear the loss: one call per clip, cut afterwards
        streams = [None if reports else [d for packets in layer_session(clip, face, kbps).packets() for d in packets]
                   for clip, face, _ in subjects]
        clean: list[np.ndarray] = []  # per clip, from the first pattern: no loss
        for label, rate, kind, burst in LAYER_PATTERNS:
            means, fifths, costs, under = [], [], [], []
            for c, ((clip, face, frames), stream) in enumerate(zip(subjects, streams)):
                for seed in range(seeds if rate else 1):
                    rng = np.random.default_rng(seed)
                    if stream is None:  # the sender hears the receiver: the call itself changes with the loss
                        drawn = reported_call(clip, face, kbps, pattern_loss(8 * len(frames), rate, kind, burst, rng))
                    else:
                        kept = arriving(stream, pattern_loss(len(stream), rate, kind, burst, rng),
                                        np.random.default_rng(seed + 1000) if rate else None, 0.05, 0.02)
                        drawn = drawn_frames(kept, face, len(frames))
                    scores = shown_psnr(drawn, frames)
                    if not rate:
                        clean.append(scores)
                    base = clean[c]
                    means.append(scores.mean())
                    fifths.append(np.percentile(scores, 5))
                    costs.append(base.mean() - scores.mean())
                    under.append(100 * np.mean(scores < base - 1.0))
            print(f"| {kbps:g} | {label} | {np.mean(means):.2f} | {np.mean(fifths):.2f} | {np.mean(costs):.2f} | "
                  f"{np.mean(under):.1f} % |", flush=True)


def bench_loss(dumps: list[Path], seeds: int) -> None:
    print("| copies | bits/frame | " + " | ".join(f"{r:.0%} random" for r in LOSSES) + " | bursts of 3 (6 %) |")
    print("|---|---|" + "---|" * (len(LOSSES) + 1))
    for copies in range(4):
        bits: list[float] = []
        cells: dict[int, list[float]] = {c: [] for c in range(len(LOSSES) + 1)}
        for path in dumps:
            stream, head, n = datagrams(path, copies)
            bits.append(8 * (sum(map(len, stream)) - head) / n)
            for seed in range(seeds):
                rng = np.random.default_rng(seed)
                for c, (rate, burst) in enumerate([(r, 1) for r in LOSSES] + [(0.06, 3)]):
                    cells[c].append(100 * frames_good(stream, lose(len(stream), rate, burst, rng), n).mean())
        print(f"| {copies} | {np.mean(bits):.1f} | " + " | ".join(f"{np.mean(v):.1f}" for v in cells.values()) + " |")


def bench_header(dumps: list[Path]) -> None:
    print("| layout | header bytes | bits/frame | + header every keyframe | every 5th | every 30th |")
    print("|---|---|---|---|---|---|")
    for suffix, label in (("paper.npz", "paper"), ("npz", "mouth (default)"), ("full.npz", "full")):
        rows = []
        for path in dumps:
            path = path.with_suffix("." + suffix)
            if path.exists():
                stream, head, n = datagrams(path, 0)
                keys = -(-n // round(read_dump(path)[1]))  # fd-send: a keyframe a second
                base = 8 * (sum(map(len, stream)) - head) / n
                rows.append((head, base, *(8 * head * (keys - 1) // every / n for every in (1, 5, 30))))
        if rows:
            r = np.mean(rows, axis=0)
            print(f"| {label} | {r[0]:.0f} | {r[1]:.1f} | +{r[2]:.1f} ({100 * r[2] / r[1]:.0f} %) | "
                  f"+{r[3]:.1f} ({100 * r[3] / r[1]:.0f} %) | +{r[4]:.1f} ({100 * r[4] / r[1]:.0f} %) |")


def bench_flood(rates: list[int], seconds: float) -> None:
    """Real frames delivered by fd-recv --key while junk datagrams arrive at each rate."""
    from facedeform.common.keys import read_key
    from facedeform.protocol.secure import SecureSealer
    from facedeform.protocol.secure_stream import seal_stream
    from tests.test_receiver_tools import smooth_tracks, stream_packets
    from tests.test_secure_transport import flood, junk_for

    n = round(25 * seconds)
    with tempfile.TemporaryDirectory() as tmp:
        key_file = Path(tmp) / "k.key"
        subprocess.run([sys.executable, "-m", "facedeform.sender.keygen", str(key_file)], check=True, cwd=ROOT,
                       stderr=subprocess.DEVNULL)
        sealed = seal_stream(SecureSealer(read_key(str(key_file))), [p for p, _ in stream_packets(smooth_tracks(n))])
        print("| junk datagrams/s (asked) | junk sent | counted by fd-recv | real frames good | concealed |")
        print("|---|---|---|---|---|")
        for rate in rates:
            proc = subprocess.Popen([sys.executable, "-m", "facedeform.receiver.cli", "--listen", "udp://127.0.0.1:0",
                                     "-o", str(Path(tmp) / "out.y4m"), "--size", "64", "--json", "--key", str(key_file),
                                     "--timeout", "2"], stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, cwd=ROOT)
            port = int(proc.stderr.readline().decode().rsplit(":", 1)[1])
            sent = flood(sealed, port, rate, 2 / 25, junk_for(sealed))
            stats = json.loads(proc.communicate(timeout=300)[1].decode().strip().splitlines()[-1])
            s = stats["security"]
            print(f"| {rate} | {sent} | {s['auth_failures'] + s['replays']} | "
                  f"{stats['frames'] - stats['concealed']} of {n} | {stats['concealed']} |", flush=True)


def main() -> None:
    p = ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("what", choices=("loss", "bursts", "udp", "header", "flood", "layer"))
    p.add_argument("dumps", nargs="*", type=Path,
                   help="fd-send --dump files (the default layout's); for layer, videos (CLIP.fdface beside each)")
    p.add_argument("--bitrates", type=float, nargs="*", default=[4.0, 10.0], help="layer: kbit/s")
    p.add_argument("--reports", action="store_true",
                   help="layer: the receiver reports to the sender as fd-recv does (datagrams lost, not reordered)")
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--key-interval", type=int, help="bursts: frames between keyframes (default: fd-send's over udp://)")
    p.add_argument("--copies", type=int, default=COPIES, help="bursts: frames packets each datagram carries again")
    p.add_argument("--frames-per-packet", type=int, default=DATAGRAM_FRAMES,
                   help="bursts: frames a packet (and datagram) holds (default: fd-send's over udp://)")
    p.add_argument("--rates", type=int, nargs="*", default=[0, 2000, 5000, 10000, 20000, 40000])
    p.add_argument("--seconds", type=float, default=6.0, help="flood: length of the call")
    args = p.parse_args()
    if args.what == "loss":
        bench_loss(args.dumps, args.seeds)
    elif args.what == "bursts":
        bench_bursts(args.dumps, args.seeds, args.key_interval, args.copies, args.frames_per_packet)
    elif args.what == "udp":
        bench_udp(args.dumps, args.seeds)
    elif args.what == "header":
        bench_header(args.dumps)
    elif args.what == "layer":
        bench_layer(args.dumps, args.bitrates, args.seeds, args.reports)
    else:
        bench_flood(args.rates, args.seconds)


if __name__ == "__main__":
    raise SystemExit(run_main("bench_loss.py", lambda: main() or 0))
