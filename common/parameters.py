"""The registry of the parameters a stream can carry: each one's name, group, slot, step, limits and layouts.

Every other module reads its parameters here: the deformer and the receiver place values by
slot (their place in the deformer's full vector), the quantiser scales the step by the quality
level (protocol/quantise.py), the sender's fit keeps to the limits and its layouts are built
from the groups, and docs/parameters.md is this registry printed
(docs/make_parameters_table.py; a test keeps the two equal). Groups added later
come last, so that the older layouts keep their slots.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: Steps at the default quality level, by kind: degrees for angles; base-face units for lengths (and
#: for the motion basis's coefficients, scaled so that one unit moves a vertex by one); the lids
#: (0 open .. 1 closed) a step that moves the lid about as far as a length's step does.
STEPS = {"angle": 0.25, "length": 0.002, "lid": 0.05}
#: Most patterns in a person's motion basis, each one parameter.
MAX_COMPONENTS = 16
#: The mouth's new free points (beyond the paper's F2, F3, F8, F9): "l"/"r" face-left/right, "u"/"l"/"o"
#: upper, lower, middle of the lip; codec/model/mouth.py gives their landmarks.
MOUTH_POINTS = ("lip_ul", "lip_ur", "lip_ll", "lip_lr", "lip_uo", "lip_lo")

#: Group -> (names, kind of each name (one for all, or per name), what the group is).
_GROUPS: dict[str, tuple[tuple[str, ...], str | tuple[str, ...], str]] = {
    "paper": (("theta", "v2x", "v2y", "v2z", "v3x", "v3y", "v3z", "v8x", "v8y", "v8z", "v9x", "v9y", "v9z"),
              ("angle",) + ("length",) * 12,
              "the paper's jaw angle and V2, V3, V8, V9: the inner lips' mid-points and the mouth corners"),
    "upper": (("brow_l_y", "brow_r_y", "brow_inner", "brow_knit", "lid_l", "lid_r", "cheek_l", "cheek_r"),
              ("length",) * 4 + ("lid",) * 2 + ("length",) * 2,
              "brows, upper lids (0 open, 1 closed) and cheeks"),
    "gaze": (("gaze_yaw", "gaze_pitch"), "angle", "the eyes' direction"),
    "pose": (("rx", "ry", "rz", "tx", "ty", "tz"), ("angle",) * 3 + ("length",) * 3,
             "the head's rotation vector and translation (codec/model/head_pose.py)"),
    "mouth": (tuple(f"{p}_{a}" for p in MOUTH_POINTS for a in "xyz") + ("jaw_x", "jaw_y", "jaw_z"), "length",
              "six more lip points and the jaw's translation"),
    "basis": (tuple(f"basis_{i}" for i in range(MAX_COMPONENTS)), "length",
              "coefficients of the person's own motion basis (their face file)"),
    "global": (("gx", "gy", "gs", "gr"), ("length", "length", "length", "angle"),
               "the whole frame's motion against the reference picture: shift (face heights), zoom - 1, roll"),
    "body": (("bx", "by"), "length",
             "the body's own shift below the chin, before the frame's motion (face heights of the reference)"),
}

_GROUP = {g: names for g, (names, _, _) in _GROUPS.items()}
PAPER_PARAMS = _GROUP["paper"]
UPPER_PARAMS = _GROUP["upper"]
GAZE_PARAMS = _GROUP["gaze"]
POSE_PARAMS = _GROUP["pose"]
MOUTH_PARAMS = _GROUP["mouth"]
BASIS_PARAMS = _GROUP["basis"]
GLOBAL_PARAMS = _GROUP["global"]
BODY_PARAMS = _GROUP["body"]
#: Where the picture's head, camera and body are, not what the face does: a coding basis keeps them on
#: axes of their own, and a face drawn at rest keeps them.
PLACING_PARAMS = POSE_PARAMS + GLOBAL_PARAMS + BODY_PARAMS
#: The lids alone, which the default layouts carry beside the mouth (a blink the face's own basis may not know).
LID_PARAMS = ("lid_l", "lid_r")
ROTATION_PARAMS = POSE_PARAMS[:3]
#: The deformer's full vector: every group, in slot order.
EXTENDED_PARAMS: tuple[str, ...] = tuple(n for names in _GROUP.values() for n in names)

#: The layouts that do not depend on the face; "personal" (sender/analysis.py) is the face's own basis
#: (after the paper's 13 when the basis refines them) with the lids and the head's rotation.
LAYOUTS: dict[str, tuple[str, ...]] = {
    "paper": PAPER_PARAMS + ROTATION_PARAMS,
    "full": PAPER_PARAMS + UPPER_PARAMS + POSE_PARAMS,
    "mouth": PAPER_PARAMS + MOUTH_PARAMS + LID_PARAMS + ROTATION_PARAMS,
}
_PERSONAL = BASIS_PARAMS + LID_PARAMS + ROTATION_PARAMS
#: What the code holds each value to, where it does: the fit's jaw angle (degrees), the lids' closing.
_LIMITS = {"theta": (-15.0, 45.0), "lid_l": (-math.inf, 1.0), "lid_r": (-math.inf, 1.0)}


@dataclass(frozen=True)
class Parameter:
    """One parameter: ``slot`` is its index in EXTENDED_PARAMS; ``step`` its quantiser step at the
    default quality level; ``limits`` (low, high), infinite where nothing bounds it; ``layouts`` the
    named layouts that hold it."""

    name: str
    group: str
    slot: int
    kind: str
    step: float
    limits: tuple[float, float]
    layouts: tuple[str, ...]


def _registry() -> dict[str, Parameter]:
    out: dict[str, Parameter] = {}
    for group, (names, kinds, _) in _GROUPS.items():
        for i, name in enumerate(names):
            kind = kinds if isinstance(kinds, str) else kinds[i]
            held = tuple(lay for lay, members in LAYOUTS.items() if name in members)
            held += ("personal",) if name in _PERSONAL else ()
            limits = _LIMITS.get(name, (-math.inf, math.inf))
            out[name] = Parameter(name, group, len(out), kind, STEPS[kind], limits, held)
    return out


PARAMETERS: dict[str, Parameter] = _registry()


def slots(names) -> list[int]:
    """The slots of ``names``; KeyError names the first one the registry does not hold."""
    return [PARAMETERS[n].slot for n in names]


def span(names) -> slice:
    """The slots of ``names`` as a slice; ValueError unless they are consecutive and in slot order."""
    first = PARAMETERS[names[0]].slot
    if slots(names) != list(range(first, first + len(names))):
        raise ValueError(f"{names!r} do not hold consecutive slots")
    return slice(first, first + len(names))


def table() -> str:
    """The registry as the Markdown of docs/parameters.md."""
    lines = ["# Parameters", "",
             "Written by `python docs/make_parameters_table.py` from the registry in `common/parameters.py`;",
             "a test keeps this file equal to it. Steps are at the default quality level (3); each level halves",
             "the steps of the one below. Kinds: angle in degrees, length in base-face units, lid 0 open .. 1 closed.",
             "The personal layout also holds the paper's 13 when the person's basis refines them.", ""]
    for group, (names, _, about) in _GROUPS.items():
        lines += [f"## {group}: {about}", "", "| slot | name | kind | step | limits | layouts |",
                  "|---|---|---|---|---|---|"]
        for n in names:
            p = PARAMETERS[n]
            limits = "" if p.limits == (-math.inf, math.inf) else f"{p.limits[0]:g} .. {p.limits[1]:g}"
            lines.append(f"| {p.slot} | {n} | {p.kind} | {p.step:g} | {limits} | {', '.join(p.layouts)} |")
        lines.append("")
    return "\n".join(lines)
