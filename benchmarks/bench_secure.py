"""What sealing a stream costs: bits per frame, latency, and seal/open throughput.

Codes the parameters of a clip (a dump from ``fd-send CLIP --dump DUMP.npz``;
default: the bundled sample, analysed first) at several frames per packet and
tag lengths, and prints a Markdown table: bits per frame in clear and sealed
(byte stream, sync bytes included; per-frame packets only, the header and
preamble once per stream apart), the overhead, the packing latency (a frame
waits for the rest of its packet) and the crypto time per packet. Then seal and
open throughput for a typical frame packet and a 1 KiB model chunk.
"""

import os
import tempfile
import time
from pathlib import Path

import numpy as np

from facedeform.common.cli import ArgumentParser, run_main
from facedeform.protocol.secure import SecureOpener, SecureSealer
from facedeform.protocol.stream import PacketEncoder, frame_bytes
from facedeform.sender.session import first_basis, read_dump, stream_header

ROOT = Path(__file__).resolve().parents[1]
KEY = os.urandom(32)


def clip_params(dump: str | None) -> tuple[np.ndarray, np.ndarray, tuple[str, ...], float]:
    if dump is None:
        from facedeform.sender.cli import main as send

        dump = str(Path(tempfile.mkdtemp()) / "sample.npz")
        send([str(ROOT / "samples" / "grid_bbaf2n.mpg"), "-o", os.devnull, "--dump", dump, "-q"])
    names, fps, params, found = read_dump(dump)
    return params, found, names, fps


def frame_packets(params, found, names, fps, fpp) -> list[bytes]:
    """The frame packets fd-send sends for the clip (its header: coding basis, static flags)."""
    header = stream_header(names, fps, "00" * 32, basis=first_basis(names, fps, list(zip(params, found))))
    enc = PacketEncoder(header, fpp)
    return [p for x, f in zip(params, found) for p in enc.frame(x, f)] + enc.end()


def crypto_us(packets: list[bytes], tag_bits: int) -> float:
    """Seal and open time per packet, microseconds (best of 5)."""
    best = float("inf")
    for _ in range(5):
        sealer, opener = SecureSealer(KEY, tag_bits), SecureOpener(KEY)
        opener.preamble(sealer.preamble())
        started = time.perf_counter()
        for p in packets:
            assert opener.open(sealer.seal(p)) == p
        best = min(best, (time.perf_counter() - started) / len(packets))
    return best * 1e6


def throughput(size: int, n: int = 20000) -> str:
    packet = os.urandom(size)
    sealer, opener = SecureSealer(KEY), SecureOpener(KEY)
    opener.preamble(sealer.preamble())
    started = time.perf_counter()
    sealed = [sealer.seal(packet) for _ in range(n)]
    seal_s = time.perf_counter() - started
    started = time.perf_counter()
    for s in sealed:
        opener.open(s)
    open_s = time.perf_counter() - started
    return (f"| {size} | {n / seal_s:,.0f} | {size * n / seal_s / 1e6:.2f} | {n / open_s:,.0f} | "
            f"{size * n / open_s / 1e6:.2f} |")


def main(argv=None) -> int:
    p = ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dump", nargs="?", help="parameter dump (.npz) from fd-send --dump; default: the sample clip")
    args = p.parse_args(argv)
    params, found, names, fps = clip_params(args.dump)
    n = len(params)
    print(f"{n} frames at {fps:g} fps, {len(names)} parameters\n")
    print("| frames/packet | packing latency ms | tag bits | clear bits/frame | sealed bits/frame "
          "| overhead bits/frame | crypto us/packet |")
    print("|---|---|---|---|---|---|---|")
    for fpp in (1, 2, 3, 4):
        packets = frame_packets(params, found, names, fps, fpp)
        clear = 8 * len(frame_bytes(packets)) / n
        for tag_bits in (32, 64, 128):
            sealer = SecureSealer(KEY, tag_bits)
            sealed = 8 * len(frame_bytes(sealer.seal_all(packets), sealed=True)) / n
            print(f"| {fpp} | {1000 * (fpp - 1) / fps:.0f} | {tag_bits} | {clear:.1f} | {sealed:.1f} | "
                  f"{sealed - clear:.1f} | {crypto_us(packets, tag_bits):.0f} |", flush=True)
    print("\n| packet bytes | seal packets/s | seal MB/s | open packets/s | open MB/s |")
    print("|---|---|---|---|---|")
    for size in (12, 1031):
        print(throughput(size), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(run_main("bench_secure.py", lambda: main() or 0))
