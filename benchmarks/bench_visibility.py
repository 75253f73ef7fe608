"""How far the receiver's picture moves when the parameters are quantised: renders of what the
decoder outputs against renders of the unquantised parameters, frame by frame.

The bitstream's goal is a quantiser fine enough that a viewer cannot tell the two renders apart;
``bench_bitstream.py`` gives the error as vertex displacement, this gives it in the pixels a viewer
sees. Dumps as for ``bench_bitstream.py`` (``fd-send CLIP -o /dev/null --dump DUMP.npz --params
LAYOUT``); fd-send's header, coding basis and dead zone; the generic face at the receiver's default
512x512. Prints a Markdown table per clip and level: bits per frame, PSNR and SSIM inside the face
(experiment/metrics.py, as fd-experiment measures), the share of the face's pixels that differ by
more than ``--threshold`` grey levels in any channel, and the worst frame's PSNR.
"""

from pathlib import Path

import numpy as np

from facedeform.codec.model.face_model import load_base_face
from facedeform.common.cli import ArgumentParser, run_main
from facedeform.common.parameters import LAYOUTS
from facedeform.experiment.metrics import psnr, ssim
from facedeform.protocol.stream import PacketEncoder, frame_bytes
from facedeform.receiver.face_view import BACKGROUND, FaceView
from facedeform.sender.session import first_basis, read_dump, stream_header


def face_pixels(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels where either render shows the face."""
    return np.any(a != BACKGROUND, axis=2) | np.any(b != BACKGROUND, axis=2)


def bench(path: Path, layout_name: str, qualities: list[int], args, face) -> list[str]:
    layout, fps, params, found = read_dump(path, LAYOUTS[layout_name])
    basis = first_basis(layout, fps, list(zip(params, found)))
    view = FaceView(stream_header(layout, fps, face.content_id, basis=basis), face, (args.size, args.size))
    reference = [view.render(p) for p in params]
    rows = []
    for quality in qualities:
        enc = PacketEncoder(stream_header(layout, fps, face.content_id, quality, basis=basis), args.frames_per_packet)
        packets, decoded = [], []
        for p, seen in zip(params, found):
            packets += enc.frame(p, seen)
            decoded.append(view.render(enc.reconstruction))
        packets += enc.end()
        masks = [face_pixels(r, x) for r, x in zip(reference, decoded)]
        moved = [np.abs(r.astype(np.int16) - x).max(axis=2)[m] > args.threshold
                 for r, x, m in zip(reference, decoded, masks)]
        share = sum(int(v.sum()) for v in moved) / sum(v.size for v in moved)
        worst = min(psnr([r], [x], [m]) for r, x, m in zip(reference, decoded, masks))
        bits = 8 * len(frame_bytes(packets)) / len(params)
        rows.append(f"| {path.stem} | {layout_name} | {quality} | {bits:.1f} | {psnr(reference, decoded, masks):.1f} | "
                    f"{ssim(reference, decoded, masks):.4f} | {100 * share:.2f} | {worst:.1f} |")
    return rows


def main() -> None:
    p = ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dumps", nargs="+", type=Path, help="fd-send --dump files (.npz)")
    p.add_argument("--params", choices=sorted(LAYOUTS), default="paper", help="layout to code (default paper)")
    p.add_argument("--qualities", type=int, nargs="*", default=[1, 2, 3, 4])
    p.add_argument("--frames-per-packet", type=int, default=2)
    p.add_argument("--size", type=int, default=512, help="square render size in pixels (default 512)")
    p.add_argument("--threshold", type=int, default=8, help="grey levels a pixel must move to count (default 8)")
    args = p.parse_args()
    face = load_base_face()
    print(f"renders {args.size}x{args.size}, generic face, {args.frames_per_packet} frames per packet; "
          f"moved: face pixels off by more than {args.threshold} grey levels")
    print("| clip | layout | quality | bits/frame | PSNR dB | SSIM | moved % | worst frame PSNR dB |")
    print("|---|---|---|---|---|---|---|---|")
    for path in args.dumps:
        for row in bench(path, args.params, args.qualities, args, face):
            print(row, flush=True)


if __name__ == "__main__":
    raise SystemExit(run_main("bench_visibility.py", lambda: main() or 0))
