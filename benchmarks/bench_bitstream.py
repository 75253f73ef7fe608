"""Bits per frame of the stream format on parameter dumps, with the error of what the decoder outputs beside each.

Dumps come from ``fd-send CLIP -o /dev/null --dump DUMP.npz --params paper|mouth|full``
(unquantised parameters: the sender's only hold is the encoder's dead zone). As fd-send does, the
stream codes the principal axes of the first second's motion unless ``--no-basis``.
Prints a Markdown table: clip, layout, quality, dead zone, bits per frame
(entropy-coded payload, framing, total), bit/s at the clip's frame rate, the
largest and rms vertex error of every decoded frame (interpolated ones too)
against the unquantised parameters of that frame (pixels for a face 380 px
tall: a 512x512 receiver view; head pose included), largest angle error, encode
and decode frames per second. A ``--params paper`` dump gives two layouts: the
paper's 13 parameters, and with head rotation (what fd-send sends).
"""

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from facedeform.codec.model.deform import Deformer, extended_params
from facedeform.codec.model.face_model import load_base_face
from facedeform.common.cli import ArgumentParser, run_main
from facedeform.common.parameters import LAYOUTS, PAPER_PARAMS
from facedeform.protocol.framing import DELTA, KEY, body_bits, kind_of
from facedeform.protocol.quantise import QUALITIES
from facedeform.protocol.stream import VERSION, Frame, PacketEncoder, StreamDecoder, frame_bytes
from facedeform.sender.session import first_basis, read_dump, stream_header

FACE_PX = 512 / 1.35  # receiver framing: the view is 1.35 face heights tall
ANGLES = ("theta", "rx", "ry", "rz")
#: Table labels by layout: fd-send's, with "paper" for the paper's 13 alone and "paper+rotation" for what
#: --params paper sends.
LABELS = {**{names: name for name, names in LAYOUTS.items()}, PAPER_PARAMS: "paper",
          LAYOUTS["paper"]: "paper+rotation"}


def payload_bits(packets: list[bytes]) -> int:
    """Entropy-coded bits of key and delta packets (sync and type bytes and the check excluded)."""
    return sum(body_bits(p) for p in packets if kind_of(p) in (KEY, DELTA))


def vertices(deformer: Deformer, layout: tuple[str, ...], params: np.ndarray) -> np.ndarray:
    """(n, 468, 3) meshes the receiver draws for (n, k) parameters of ``layout``."""
    return np.array([deformer.deform_extended(p) for p in extended_params(layout, params)])


def bench(path: Path, layout: tuple[str, ...], quality: int, dead_zone: float, args, deformer: Deformer) -> str:
    _, fps, params, found = read_dump(path, layout)
    basis = None if args.no_basis else first_basis(layout, fps, list(zip(params, found)))
    header = replace(stream_header(layout, fps, "00" * 32, quality, basis=basis, divisor=args.divisor),
                     skip_static=not args.no_static)
    enc = PacketEncoder(header, args.frames_per_packet, dead_zone=dead_zone)
    head = enc.header()
    packets, sent = [], {}
    started = time.perf_counter()
    for i, (x, seen) in enumerate(zip(params, found)):
        packets += enc.frame(x, seen)
        if i % args.divisor == 0:
            sent[i] = enc.reconstruction
    packets += enc.end()
    encode_s = time.perf_counter() - started
    dec = StreamDecoder()
    started = time.perf_counter()
    frames = [e for e in dec.feed(frame_bytes(head) + frame_bytes(packets)) + dec.close() if isinstance(e, Frame)]
    decode_s = time.perf_counter() - started
    n = len(params)
    assert len(frames) == n and not dec.stats.damaged
    assert all(np.array_equal(frames[i].params, r) for i, r in sent.items()), "decoder differs from encoder"
    got = np.array([f.params for f in frames])
    total = 8 * len(frame_bytes(packets)) / n
    payload = payload_bits(packets) / n
    err = np.linalg.norm(vertices(deformer, layout, got) - vertices(deformer, layout, params), axis=2).max(axis=1)
    err *= FACE_PX
    angle = [layout.index(a) for a in ANGLES if a in layout]
    angle_err = np.abs(params[:, angle] - got[:, angle]).max()
    name = LABELS.get(layout, "other")
    return (f"| {path.stem} | {name} | {quality} | {dead_zone:g} | {payload:.1f} | {total - payload:.1f} | "
            f"{total:.1f} | {total * fps:.0f} | {err.max():.2f} | {np.sqrt((err ** 2).mean()):.2f} | "
            f"{angle_err:.3f} | {n / encode_s:.0f} | {n / decode_s:.0f} |")


def main() -> None:
    p = ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dumps", nargs="+", type=Path, help="sender --dump files (.npz)")
    p.add_argument("--frames-per-packet", type=int, default=4)
    p.add_argument("--qualities", type=int, nargs="*", default=list(QUALITIES))
    p.add_argument("--dead-zones", type=float, nargs="*", default=[0.5, 1.0],
                   help="encoder dead zones in steps (0.5: plain rounding)")
    p.add_argument("--divisor", type=int, default=1, help="send one frame in N, the decoder interpolates")
    p.add_argument("--no-static", action="store_true", help="static-frame flags off (fd-send sets them)")
    p.add_argument("--no-basis", action="store_true",
                   help="code each parameter on its own (fd-send --no-basis), not the first second's principal axes")
    args = p.parse_args()
    deformer = Deformer(load_base_face())
    print(f"frames per packet: {args.frames_per_packet}, divisor {args.divisor}, static flags "
          f"{'off' if args.no_static else 'on'}, basis {'off' if args.no_basis else 'on'}, "
          f"format version {VERSION}; "
          f"vertex error in px for a face {FACE_PX:.0f} px tall")
    print("| clip | layout | quality | dead zone | payload bits/frame | framing bits/frame | total bits/frame | "
          "bit/s | max vertex err px | rms vertex err px | max angle err deg | encode fps | decode fps |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for path in args.dumps:
        names = read_dump(path)[0]
        layouts = [PAPER_PARAMS, names] if names == LAYOUTS["paper"] else [names]
        for layout in layouts:
            for quality in args.qualities:
                for dead_zone in args.dead_zones:
                    print(bench(path, layout, quality, dead_zone, args, deformer), flush=True)


if __name__ == "__main__":
    raise SystemExit(run_main("bench_bitstream.py", lambda: main() or 0))
