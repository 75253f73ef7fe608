"""Trains the coding bases of the layouts every package holds (protocol/layouts.json) on fd-send
parameter dumps, and measures them clip by clip held out.

Per layout, the basis of :func:`protocol.basis.principal_basis` over every frame with a face of
every dump of that layout; the same layout with the head's translation, with the frame's
global motion and with the body's shift, as a face with a reference picture sends it (those on
axes of their own), is held too. Prints the table's sha256 for protocol/layouts.py.

Dumps: ``fd-send CLIP -o /dev/null --dump CLIP.LAYOUT.npz --params LAYOUT`` for each dev clip
and LAYOUT in paper, mouth, full (fd-send's other options at their defaults).

``--check`` codes each dump four ways (level 3, 2 frames per packet, a keyframe a second) and
prints a Markdown table of stream bits per frame: no basis, the call's own first second, the
basis of the other clips' dumps only (what a speaker outside the training set gets), and the
basis of all of them.

    .venv/bin/python benchmarks/train_layouts.py dumps/*.npz [--check]
"""

import hashlib
from collections import defaultdict
from pathlib import Path

import numpy as np

from facedeform.common.cli import ArgumentParser, run_main
from facedeform.common.parameters import BODY_PARAMS, GLOBAL_PARAMS, POSE_PARAMS
from facedeform.protocol import layouts as layouts_module
from facedeform.protocol.basis import SCALE
from facedeform.protocol.layouts import table_bytes
from facedeform.protocol.stream import PacketEncoder, frame_bytes
from facedeform.sender.session import first_second, read_dump, sample_basis, stream_header


def widened(names: tuple[str, ...], basis: np.ndarray, extra: tuple[str, ...]) -> tuple[tuple[str, ...], np.ndarray]:
    """``names`` + ``extra`` and ``basis`` with the extra names on axes of their own."""
    k, out = len(names), np.zeros((len(names) + len(extra),) * 2, np.int8)
    out[:k, :k] = basis
    out[np.arange(k, len(out)), np.arange(k, len(out))] = SCALE
    return names + extra, out


def _translation(names: tuple[str, ...]) -> tuple[str, ...]:
    """The head's translation, which a face with a reference picture adds unless ``names`` ("full") has it."""
    return () if "tx" in names else POSE_PARAMS[3:]


def picture_extras(names: tuple[str, ...]) -> tuple[tuple[str, ...], ...]:
    """What a face with a reference picture adds to ``names``: the head's translation and the frame's
    global motion."""
    return tuple(dict.fromkeys(((), _translation(names), _translation(names) + GLOBAL_PARAMS)))


def body_extras(names: tuple[str, ...]) -> tuple[tuple[str, ...], ...]:
    """The same with the body's shift: held after every layout of :func:`picture_extras`, which kept
    their indices when the body's motion came."""
    return _translation(names) + BODY_PARAMS, _translation(names) + GLOBAL_PARAMS + BODY_PARAMS


def bits(dump, basis) -> float:
    """Stream bits per frame of ``dump`` (read_dump's tuple) with the coding ``basis``."""
    names, fps, params, found = dump
    encoder = PacketEncoder(stream_header(names, fps, "00" * 32, basis=basis), 2)
    packets = [p for x, f in zip(params, found) for p in encoder.frame(x, f)] + encoder.end()
    return 8 * len(frame_bytes(packets)) / len(params)


def learnt(dumps: list) -> np.ndarray:
    names = dumps[0][0]
    basis = sample_basis(names, list(np.concatenate([params[found] for _, _, params, found in dumps])))
    if basis is None:
        raise SystemExit(f"the dumps of {len(names)} parameters hardly move: no basis")
    return basis


def main() -> None:
    p = ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dumps", nargs="+", type=Path)
    p.add_argument("--check", action="store_true", help="print bits per frame, clip by clip held out")
    args = p.parse_args()
    layouts: dict[tuple[str, ...], dict[str, tuple]] = defaultdict(dict)
    for path in args.dumps:
        dump = read_dump(path)
        layouts[dump[0]][path.name.split(".")[0]] = dump
    bases = {names: learnt(list(by_clip.values())) for names, by_clip in layouts.items()}
    table = [widened(names, basis, extra) for extras in (picture_extras, body_extras)
             for names, basis in bases.items() for extra in extras(names)]
    data = table_bytes(table)
    layouts_module.PATH.write_bytes(data)
    digest = hashlib.sha256(data).hexdigest()
    print(f"{layouts_module.PATH}: {len(table)} layouts, {len(data)} bytes, sha256 {digest}")
    layouts_module.SHA256 = digest  # the table just written, for the check's headers
    layouts_module.shipped.cache_clear()
    for names, by_clip in layouts.items() if args.check else ():
        print(f"\n{len(names)} parameters ({', '.join(names[:4])}, ...)\n")
        print("| clip | no basis | its first second | the other clips' | all clips' |\n|---|---|---|---|---|")
        rows = []
        for clip, (_, fps, params, found) in by_clip.items():
            first = [x for x, seen in zip(params[:first_second(fps)], found) if seen]
            ways = (None, sample_basis(names, first), learnt([d for c, d in by_clip.items() if c != clip]),
                    bases[names])
            rows.append([bits(by_clip[clip], b) for b in ways])
            print(f"| {clip} | " + " | ".join(f"{v:.1f}" for v in rows[-1]) + " |")
        print("| mean | " + " | ".join(f"{v:.1f}" for v in np.mean(rows, axis=0)) + " |")


if __name__ == "__main__":
    raise SystemExit(run_main("train_layouts.py", lambda: main() or 0))
