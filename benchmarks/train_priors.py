"""Trains the starting counts of the stream's entropy models (protocol/priors.json) on fd-send parameter dumps,
and measures them leave-one-clip-out.

Each dump is coded as fd-send codes it (its layout, the coding basis of its first
second, a keyframe a second, static flags, dead zone 1) at every quality level,
with models that count what they code. A model's starting counts are its counts
over all dumps at that level, scaled to a total of 16: enough to spare the
first symbols' learning after each keyframe, few enough that the call's own
data takes over within the second.

Dumps: ``fd-send CLIP -o /dev/null --dump CLIP.LAYOUT.npz --params LAYOUT`` for each dev clip
and LAYOUT in paper, mouth, full (fd-send's other options at their defaults).

``--check`` codes each dump three ways (2 frames per packet) and prints a
Markdown table of stream bits per frame: models that start from nothing, the
table trained on every dump, and one trained on the other clips' dumps only
(what a speaker outside the training set gets).
"""

import hashlib
import json
from collections import defaultdict
from pathlib import Path
from unittest import mock

from facedeform.common.cli import ArgumentParser, run_main
from facedeform.protocol import encoder as encoder_module
from facedeform.protocol.arith import AdaptiveBit
from facedeform.protocol.priors import PATH, key_name, models_for
from facedeform.protocol.quantise import QUALITIES
from facedeform.protocol.stream import PacketEncoder, frame_bytes
from facedeform.sender.session import first_basis, read_dump, stream_header

SCALE = 16


class CountingBit(AdaptiveBit):
    """An adaptive bit that also adds every bit it codes to ``total`` ([zeros, ones])."""

    __slots__ = ("total",)

    def __init__(self, total: list[int]) -> None:
        super().__init__()
        self.total = total

    def update(self, bit: int) -> None:
        super().update(bit)
        self.total[bit] += 1


def code(path: Path, quality: int, models) -> float:
    """Stream bits per frame of ``path`` coded as fd-send codes it, with ``models`` in place of
    :func:`protocol.priors.models_for`."""
    names, fps, params, found = read_dump(path)
    header = stream_header(names, fps, "00" * 32, quality, basis=first_basis(names, fps, list(zip(params, found))))
    with mock.patch.object(encoder_module, "models_for", models):
        enc = PacketEncoder(header, 2)
        packets = [p for x, f in zip(params, found) for p in enc.frame(x, f)] + enc.end()
    return 8 * len(frame_bytes(packets)) / len(params)


def counts(paths: list[Path], quality: int) -> dict[str, list[int]]:
    """{model key name: [zeros, ones]} coded over ``paths`` at ``quality``."""
    totals: dict[str, list[int]] = defaultdict(lambda: [0, 0])
    for path in paths:
        code(path, quality, lambda header: lambda key: CountingBit(totals[key_name(key)]))
    return dict(totals)


def scaled(totals: dict[str, list[int]]) -> dict[str, list[int]]:
    out = {}
    for name, (n0, n1) in sorted(totals.items()):
        f = min(1.0, SCALE / max(1, n0 + n1))
        if round(n0 * f) or round(n1 * f):
            out[name] = [round(n0 * f), round(n1 * f)]
    return out


def train(paths: list[Path]) -> dict[str, dict[str, list[int]]]:
    return {str(q): scaled(counts(paths, q)) for q in QUALITIES}


def check(paths: list[Path]) -> None:
    everyone = train(paths)
    print("| clip | layout | quality | no starting counts | trained on all clips | trained on other clips |")
    print("|---|---|---|---|---|---|")
    for path in paths:
        clip = path.name.split(".")[0]
        others = train([p for p in paths if p.name.split(".")[0] != clip])
        for q in QUALITIES:
            flat = code(path, q, lambda header: lambda key: AdaptiveBit())
            own = code(path, q, lambda header: models_for(header, everyone))
            held_out = code(path, q, lambda header, others=others: models_for(header, others))
            print(f"| {clip} | {path.name.split('.')[1]} | {q} | {flat:.1f} | {own:.1f} | {held_out:.1f} |", flush=True)


def main() -> None:
    p = ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dumps", nargs="+", type=Path, help="fd-send --dump files (.npz), named CLIP.LAYOUT.npz")
    p.add_argument("--check", action="store_true", help="measure instead of writing the table")
    p.add_argument("-o", "--output", type=Path, default=PATH, help=f"table to write (default {PATH})")
    args = p.parse_args()
    if args.check:
        check(args.dumps)
        return
    data = json.dumps(train(args.dumps), separators=(",", ":"), sort_keys=True).encode()
    args.output.write_bytes(data)
    print(f"wrote {args.output} ({len(data)} bytes), sha256 {hashlib.sha256(data).hexdigest()}")


if __name__ == "__main__":
    raise SystemExit(run_main("train_priors.py", lambda: main() or 0))
