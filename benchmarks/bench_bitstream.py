"""Bits per frame of the stream format on parameter dumps, with the quantisation error beside each.

Dumps come from ``python -m sender.cli CLIP -o /dev/null --dump DUMP.npz``.
Prints a Markdown table: clip, layout, quality, bits per frame (entropy-coded
payload, framing, total), bit/s at the clip's frame rate, the largest and rms
vertex error of the quantised against the unquantised parameters (pixels for a
face 380 px tall: a 512x512 receiver view), largest angle error, encode and
decode frames per second.
"""

import argparse
import time
from pathlib import Path

import numpy as np

from codec.deform import PAPER_PARAMS, Deformer
from codec.face_model import load_base_face
from protocol.framing import packet_size
from protocol.quantise import QUALITIES, dequantise, quantise
from protocol.stream import Frame, Header, PacketEncoder, StreamDecoder, frame_bytes, steps_for

FACE_PX = 512 / 1.35  # receiver framing: the view is 1.35 face heights tall


def payload_bits(packets: list[bytes]) -> int:
    """Entropy-coded bits of key and delta packets (type byte, length, CRC and sync excluded)."""
    bits = 0
    for p in packets:
        if p[0] >> 5 in (2, 3):
            size = packet_size(p, 0)
            check = 2 if p[0] >> 5 == 2 else 1
            bits += 8 * (size - check - (len(p) - size) - (1 + (size - check > 128)))
    return bits


def bench(path: Path, layout: tuple[str, ...], quality: int, fpp: int, deformer: Deformer) -> str:
    d = np.load(path)
    names = tuple(str(n) for n in d["names"])
    fps = float(d["fps"])
    cols = [names.index(n) for n in layout]
    params = d["params"][:, cols]
    found = d["found"]
    header = Header(fps, layout, steps_for(layout, quality), "00" * 32, quality=quality)
    enc = PacketEncoder(header, fpp)
    head = enc.header()
    started = time.perf_counter()
    packets = [p for x, f in zip(params, found) for p in enc.frame(x, f)] + enc.end()
    encode_s = time.perf_counter() - started
    data = frame_bytes(head) + frame_bytes(packets)
    dec = StreamDecoder()
    started = time.perf_counter()
    frames = [e for e in dec.feed(data) + dec.close() if isinstance(e, Frame)]
    decode_s = time.perf_counter() - started
    n = len(params)
    assert len(frames) == n and not dec.stats.damaged
    total = 8 * len(frame_bytes(packets)) / n
    payload = payload_bits(packets) / n
    q = np.array([dequantise(quantise(x, header.steps), header.steps) for x in params])
    k = len(PAPER_PARAMS)
    err = np.array([np.linalg.norm(deformer.deform(a[:k]) - deformer.deform(b[:k]), axis=1).max()
                    for a, b in zip(params, q)]) * FACE_PX
    angle = [i for i, name in enumerate(layout) if name in ("theta", "rx", "ry", "rz")]
    angle_err = np.abs(params[:, angle] - q[:, angle]).max()
    name = "paper" if len(layout) == k else "paper+pose"
    return (f"| {path.stem} | {name} | {quality} | {payload:.1f} | {total - payload:.1f} | {total:.1f} | "
            f"{total * fps:.0f} | {err.max():.2f} | {np.sqrt((err ** 2).mean()):.2f} | {angle_err:.3f} | "
            f"{n / encode_s:.0f} | {n / decode_s:.0f} |")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dumps", nargs="+", type=Path, help="sender --dump files (.npz)")
    p.add_argument("--frames-per-packet", type=int, default=4)
    p.add_argument("--qualities", type=int, nargs="*", default=list(QUALITIES))
    args = p.parse_args()
    deformer = Deformer(load_base_face())
    print(f"frames per packet: {args.frames_per_packet}; vertex error in px for a face {FACE_PX:.0f} px tall")
    print("| clip | layout | quality | payload bits/frame | framing bits/frame | total bits/frame | bit/s | "
          "max vertex err px | rms vertex err px | max angle err deg | encode fps | decode fps |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for path in args.dumps:
        for layout in (PAPER_PARAMS, PAPER_PARAMS + ("rx", "ry", "rz")):
            for quality in args.qualities:
                print(bench(path, layout, quality, args.frames_per_packet, deformer), flush=True)


if __name__ == "__main__":
    main()
