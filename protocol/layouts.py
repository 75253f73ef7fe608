"""The parameter layouts every facedeform package holds, each with a coding basis trained on many speakers.

A header whose names and basis are one of these names it by its index, one byte, instead of
writing some 40 names and a k x k basis: the default layout's header falls from 1,825 bytes to
about 60, and so does each of the repeats a late joiner over UDP needs. The bases were learned
from fd-send's parameters of the dev clips (every frame with a face, in quantiser steps, head
pose, global and body motion on axes of their own: :func:`protocol.basis.principal_basis`); held out clip
by clip they code no more bits than each call's own first second (benchmarks/train_layouts.py,
docs/bitstream.md). A layout with the speaker's own motion basis is not here: its coefficients are
decorrelated already and it travels without a coding basis.

Part of the format: both ends must read the same table, so ``layouts.json`` is checked against
:data:`SHA256` when it is loaded; within a stream version an index never changes meaning.
"""

import base64
import json
from functools import cache
from pathlib import Path

import numpy as np

from facedeform.common.packaged import read_packaged

SHA256 = "a35b6b842279dbd96142b6a541901e9ac7a4ac758ff5b4bb8000f38b350b694f"
PATH = Path(__file__).with_name("layouts.json")


@cache
def shipped() -> tuple[tuple[tuple[str, ...], np.ndarray], ...]:
    """((names, (k, k) int8 basis), ...) in index order, checked against :data:`SHA256`; FdError (one
    line from the tools) if the installed file is missing or another."""
    out = []
    for entry in json.loads(read_packaged(PATH, SHA256, "the layout table of this stream format")):
        names = tuple(entry["names"])
        basis = np.frombuffer(base64.b64decode(entry["basis"]), dtype=np.int8).reshape(len(names), len(names))
        basis.flags.writeable = False
        out.append((names, basis))
    return tuple(out)


def shipped_basis(names: tuple[str, ...]) -> np.ndarray | None:
    """The (k, k) int8 coding basis held for the layout ``names``; None if it is not one of them."""
    return next((basis for known, basis in shipped() if known == tuple(names)), None)


def shipped_index(names: tuple[str, ...], basis: np.ndarray | None) -> int | None:
    """The index of the held layout with ``names`` and ``basis``; None if there is none."""
    if basis is None:
        return None
    return next((i for i, (known, held) in enumerate(shipped())
                 if known == tuple(names) and np.array_equal(held, basis)), None)


def table_bytes(layouts: list[tuple[tuple[str, ...], np.ndarray]]) -> bytes:
    """``layouts.json``'s bytes for ``layouts`` ((names, int8 basis), ...): what the trainer writes."""
    return (json.dumps([{"names": list(names), "basis": base64.b64encode(np.asarray(basis, np.int8).tobytes())
                         .decode("ascii")} for names, basis in layouts], indent=1) + "\n").encode("ascii")
