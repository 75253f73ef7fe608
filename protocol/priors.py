"""Trained starting counts of the stream's entropy models, one table per quality level.

The counts are part of the format: a decoder must start each keyframe's models
from the same counts as the encoder did, so ``priors.json`` is checked against
:data:`SHA256` when it is loaded, and what a version reads from it never changes. Where they
come from (fd-send's parameters of the dev clips, each model's counts scaled to
a total of 16 so the data still rules after a second) and what they save:
benchmarks/train_priors.py and docs/bitstream.md.
"""

import json
from functools import cache
from pathlib import Path

from facedeform.common.packaged import read_packaged
from facedeform.protocol.arith import AdaptiveBit
from facedeform.protocol.entropy import NewBit
from facedeform.protocol.header import Header
from facedeform.protocol.quantise import DEFAULT_QUALITY, QUALITIES

SHA256 = "c0cae46dd955b71e4bb5e5bd333fc04d3e397944ea1f9b630246bc498c50efa1"
PATH = Path(__file__).with_name("priors.json")


@cache
def tables() -> dict[str, dict[str, list[int]]]:
    """{quality level: {model key name: [n0, n1]}}, checked against :data:`SHA256`; FdError (one
    line from the tools) if the installed file is missing or another."""
    return json.loads(read_packaged(PATH, SHA256, "the entropy table of this stream format"))


def key_name(key: tuple) -> str:
    """A model's key as the table names it, e.g. ``delta.prefix.0.2.1``."""
    return ".".join(map(str, key))


def models_for(header: Header, levels: dict[str, dict[str, list[int]]] | None = None) -> NewBit:
    """What a stream's :class:`protocol.entropy.GroupState` makes its models with: the header
    level's trained counts from ``levels`` (default: :func:`tables`; custom steps take the default
    level's)."""
    table = (levels or tables())[str(header.quality if header.quality in QUALITIES else DEFAULT_QUALITY)]
    return lambda key: AdaptiveBit(*table.get(key_name(key), (0, 0)))
