"""The paper's abstract deformation levels (section 3.3): expression -> Action Units -> parameters.

codec/data/expressions.json maps an expression or viseme name to FACS AU
intensities; codec/data/au_table.json maps each AU to named parameters of
EXTENDED_PARAMS at intensity 1. Both levels are face-independent; the result
is linear in the intensities (lids clipped to at most 1, fully closed).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from facedeform.codec.data import data_path
from facedeform.common.errors import InputError
from facedeform.common.parameters import EXTENDED_PARAMS, LID_PARAMS, PARAMETERS, slots

AU_FILE = data_path("au_table.json")
EXPRESSION_FILE = data_path("expressions.json")
LIDS = slots(LID_PARAMS)

INTENSITY = (0.0, 2.0)  # the range of an expression's or AU's intensity


@dataclass(frozen=True, eq=False)
class Tables:
    """aus: AU number -> (name, (len(EXTENDED_PARAMS),) params at intensity 1);
    expressions: name -> {AU: intensity}, expressions first, then visemes."""

    aus: dict[int, tuple[str, np.ndarray]]
    expressions: dict[str, dict[int, float]]


def _read(path: str | Path) -> dict:
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path} is not valid JSON: {exc}") from None
    if not isinstance(data, dict):
        raise InputError(f"{path} must hold a JSON object")
    return data


def _number(value, what: str, lo: float = -math.inf, hi: float = math.inf) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) \
            or not lo <= value <= hi:
        raise InputError(f"{what} must be a finite number{'' if hi == math.inf else f' from {lo:g} to {hi:g}'}, "
                         f"not {value!r}")
    return float(value)


def _intensity(value, what: str) -> float:
    """An intensity: 0 none, 1 the table's full expression or AU, up to INTENSITY's top for
    exaggeration (beyond it the mesh tears: a 1e30 smile is not a face)."""
    return _number(value, f"intensity of {what}", *INTENSITY)


def _au(key, what: str) -> int:
    try:
        return int(key)
    except (TypeError, ValueError):
        raise InputError(f"{what}: {key!r} is not an AU number") from None


def load_tables(au_path: str | Path = AU_FILE, expression_path: str | Path = EXPRESSION_FILE) -> Tables:
    """Read and check both tables; any defect is an InputError with a one-line message."""
    aus: dict[int, tuple[str, np.ndarray]] = {}
    raw = _read(au_path).get("aus")
    if not isinstance(raw, dict):
        raise InputError(f"{au_path} needs an 'aus' object: AU number -> {{name, params}}")
    for key, entry in raw.items():
        au = _au(key, str(au_path))
        if not isinstance(entry, dict) or not isinstance(entry.get("params"), dict):
            raise InputError(f"{au_path}: AU {key} needs a 'params' object")
        vec = np.zeros(len(EXTENDED_PARAMS))
        for name, value in entry["params"].items():
            if name not in EXTENDED_PARAMS:
                raise InputError(f"{au_path}: AU {key} has unknown parameter {name!r}")
            vec[PARAMETERS[name].slot] = _number(value, f"{au_path}: AU {key} {name}")
        aus[au] = (str(entry.get("name", f"AU{au}")), vec)

    data = _read(expression_path)
    expressions: dict[str, dict[int, float]] = {}
    for group in ("expressions", "visemes"):
        table = data.get(group, {})
        if not isinstance(table, dict):
            raise InputError(f"{expression_path}: '{group}' must be an object")
        for name, recipe in table.items():
            if not isinstance(recipe, dict) or name in expressions:
                raise InputError(f"{expression_path}: {name!r} must be one {{AU: intensity}} object")
            expressions[name] = {}
            for key, value in recipe.items():
                au = _au(key, f"{expression_path}: {name}")
                if au not in aus:
                    raise InputError(f"{expression_path}: {name} uses AU {au}, which {au_path} lacks")
                expressions[name][au] = _number(value, f"{expression_path}: {name} AU {au}")
    if not expressions:
        raise InputError(f"{expression_path} defines no expressions")
    return Tables(aus, expressions)


@lru_cache(maxsize=1)
def default_tables() -> Tables:
    """The tables shipped in ``codec.data``, read once."""
    return load_tables()


def au_params(intensities: Mapping[int | str, float], tables: Tables | None = None) -> np.ndarray:
    """(len(EXTENDED_PARAMS),) parameters for {AU: intensity}: the weighted sum of the AU rows."""
    t = tables or default_tables()
    out = np.zeros(len(EXTENDED_PARAMS))
    for key, value in intensities.items():
        au = _au(key, "AU vector")
        if au not in t.aus:
            raise InputError(f"unknown AU {au} (known: {', '.join(str(a) for a in sorted(t.aus))})")
        out += _intensity(value, f"AU {au}") * t.aus[au][1]
    out[LIDS] = np.minimum(out[LIDS], [PARAMETERS[n].limits[1] for n in LID_PARAMS])
    return out


def expression_params(name: str, intensity: float = 1.0, tables: Tables | None = None) -> np.ndarray:
    """(len(EXTENDED_PARAMS),) parameters of a named expression or viseme at an intensity."""
    t = tables or default_tables()
    if name not in t.expressions:
        raise InputError(f"unknown expression {name!r} (known: {', '.join(t.expressions)})")
    scale = _intensity(intensity, name)
    return au_params({au: scale * v for au, v in t.expressions[name].items()}, t)
