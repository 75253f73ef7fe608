"""The person's rest face, and FAPU-like scales that carry their motion onto the base face.

Parameters are displacements from this person's rest shape. A wide mouth
opens wider in absolute terms than the base face's; dividing each displacement
by the person's own facial distances and multiplying by the base face's (as
MPEG-4 does with its FAPUs: mouth width, mouth-nose separation, eye separation,
eye-nose separation, eye opening) makes the same numbers mean the same motion
on any base face.
"""

from dataclasses import dataclass

import numpy as np

from facedeform.codec.model.face_model import BaseFace
from facedeform.codec.render.eyelids import CORNERS, LIDS
from facedeform.codec.render.mouth_interior import LOWER_LIP, UPPER_LIP
from facedeform.common.errors import InputError
from facedeform.sender.fit import BLINK_GAP

MOUTH_CORNERS = (61, 291)
SUBNASALE = 2
NOSE_TIP = 1
RATIO_LIMITS = (0.5, 2.0)  # a ratio outside this is a tracking failure, not a face


@dataclass(frozen=True)
class RestFace:
    """neutral (468, 3) pose-free rest landmarks; scale (468, 3) base-over-person ratio per
    landmark and axis; index: the frame it came from."""

    neutral: np.ndarray
    scale: np.ndarray
    index: int

    def target(self, aligned: np.ndarray, base: np.ndarray) -> np.ndarray:
        """(468, 3) pose-free landmarks -> the base face moved as this person moved from rest."""
        return base + self.scale * (aligned - self.neutral)


def fapu_ratios(neutral: np.ndarray, face: BaseFace) -> np.ndarray:
    """(468, 3) base-over-person ratios: lower face by mouth width (x) and mouth-nose separation (y),
    upper face by eye separation (x) and eye-nose separation (y), eye loops by eye opening (y);
    depth by the mean of the two in-plane ratios."""
    def units(x):
        def d(a, b):
            return float(np.linalg.norm(x[a] - x[b]))
        eye_mid = [x[list(e)].mean(axis=0) for e in CORNERS]
        mw = d(*MOUTH_CORNERS)
        mns = float(np.linalg.norm(x[SUBNASALE] - x[[UPPER_LIP, LOWER_LIP]].mean(axis=0)))
        es = float(np.linalg.norm(eye_mid[0] - eye_mid[1]))
        ens = float(np.linalg.norm(0.5 * (eye_mid[0] + eye_mid[1]) - x[NOSE_TIP]))
        return np.array([mw, mns, es, ens, d(*LIDS[0]), d(*LIDS[1])])

    r = np.clip(units(face.vertices) / np.maximum(units(neutral), 1e-9), *RATIO_LIMITS)
    mouth_level = 0.5 * (face.vertices[SUBNASALE, 1] + face.vertices[UPPER_LIP, 1])
    lower = face.vertices[:, 1] < mouth_level
    scale = np.empty((len(neutral), 3))
    scale[:, 0] = np.where(lower, r[0], r[2])
    scale[:, 1] = np.where(lower, r[1], r[3])
    for loop, ratio in zip(("eye_right", "eye_left"), r[4:]):
        scale[face.meta["loops"][loop], 1] = ratio
    scale[:, 2] = 0.5 * (scale[:, 0] + scale[:, 1])
    return scale


def choose_rest(candidates: list[tuple[int, np.ndarray, np.ndarray]], neutral: int | None = None) -> int:
    """Index of the rest frame among (frame index, (468, 3) landmarks in pixels, (468, 3) aligned).

    With ``neutral`` that frame (it must hold a face); otherwise the one with the
    mouth most closed, which for speech is the nearest a clip comes to a rest face, of those whose
    eyes are open (not under BLINK_GAP of the most open): lids measured from a blink would draw every
    open eye of the call wider than it is.
    """
    if neutral is not None:
        for index, _, _ in candidates:
            if index == neutral:
                return index
        raise InputError(f"--neutral {neutral}: no face tracked in that frame")
    openings = [float(eye_opening(landmarks)) for _, landmarks, _ in candidates]
    open_eyes = [c for c, opening in zip(candidates, openings) if eyes_open(opening, max(openings))]
    return min(open_eyes, key=lambda c: lip_gap(c[1]))[0]


def eyes_open(opening: float, most_open: float) -> bool:
    """Whether eyes as open as ``opening`` (:func:`eye_opening`) are open, not a blink: not under
    BLINK_GAP of ``most_open``, the most open they were (the tracker brings a shut eye's lids only
    about half together)."""
    return opening >= BLINK_GAP * most_open


def inter_ocular(landmarks: np.ndarray) -> np.ndarray:
    """Distance between the eye centres of (..., 468, d) landmarks -> (...): the face's yardstick."""
    lm = np.asarray(landmarks, dtype=np.float64)
    return np.linalg.norm(lm[..., CORNERS[0], :].mean(axis=-2) - lm[..., CORNERS[1], :].mean(axis=-2), axis=-1)


def lip_gap(landmarks: np.ndarray) -> np.ndarray:
    """Inner-lip gap of (..., 468, d) landmarks over their inter-ocular distance -> (...):
    a scale-free mouth opening."""
    lm = np.asarray(landmarks, dtype=np.float64)
    return np.linalg.norm(lm[..., UPPER_LIP, :] - lm[..., LOWER_LIP, :], axis=-1) / inter_ocular(lm)


def eye_opening(landmarks: np.ndarray) -> np.ndarray:
    """Mean lid gap of both eyes of (..., 468, d) landmarks, each over its eye's width -> (...):
    a scale-free eye opening (near 0 in a blink)."""
    lm = np.asarray(landmarks, dtype=np.float64)
    def ratio(lids, corners):
        return (np.linalg.norm(lm[..., lids[0], :] - lm[..., lids[1], :], axis=-1)
                / np.linalg.norm(lm[..., corners[0], :] - lm[..., corners[1], :], axis=-1))
    return 0.5 * (ratio(LIDS[0], CORNERS[0]) + ratio(LIDS[1], CORNERS[1]))
