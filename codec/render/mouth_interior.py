"""The person's open mouth in a mouth less open: teeth at their own size, the lips closing over them.

The whole picture draws the mouth opening from the person's own open mouth (the enrolment's
widest, codec/render/picture.SceneMesh). The mesh maps that picture onto the opening as it is now, so
a mouth half as open drew both rows of teeth at half their height: a thin band of small teeth
where a speaker shows the upper teeth's edges (seen on sadtalker_WDA_KatieHill). Here the
picture is remapped first, column by column between the inner lips: its upper half shows the
open mouth's top at its own scale (the upper teeth move with the upper lip), its lower half the
bottom (the lower teeth with the lower lip), and what lay between, the middle of the cavity,
is left out; once squashed by the mesh each part is drawn at its own size, and the lips cover
the teeth as they close. Closed lips leave no opening, so no teeth are drawn.
"""

from __future__ import annotations

import cv2
import numpy as np

UPPER_LIP, LOWER_LIP = 13, 14  # the inner lips' middles
STEPS = 16  # the opening's ratio moves in these steps, so that a still mouth is not remapped every frame


class MouthInterior:
    """The open mouth ``image`` (h, w, 3) and the pixels in it ``points`` (k, 2) of the mouth
    opening's vertices ``vertices`` (k,) (sorted landmark indices), with the inner lips' loops
    ``upper`` and ``lower`` (landmark indices, corner to corner)."""

    def __init__(self, image: np.ndarray, points: np.ndarray, vertices: np.ndarray, upper: list[int],
                 lower: list[int]) -> None:
        self.image = image
        at = {int(v): p for v, p in zip(vertices, np.asarray(points, dtype=np.float64))}
        self._open_gap = float(np.linalg.norm(at[UPPER_LIP] - at[LOWER_LIP]))
        height, width = image.shape[:2]
        xs = np.arange(width, dtype=np.float64)
        top, bottom = (_curve(np.array([at[v] for v in loop]), xs) for loop in (upper, lower))
        self._top = np.clip(top, 0, height - 1).astype(np.float32)
        self._bottom = np.clip(np.maximum(bottom, top), 0, height - 1).astype(np.float32)
        self._rows, self._cols = np.mgrid[0:height, 0:width].astype(np.float32)
        self._cache: tuple[float, np.ndarray] = (1.0, image)

    def ratio(self, upper_lip: np.ndarray, lower_lip: np.ndarray) -> float:
        """How open the mouth is, against the open mouth's picture, 0 to 1 in 1/STEPS: from the inner
        lips' middles' pixels in the reference picture (its scale is the open mouth's)."""
        if self._open_gap <= 0:
            return 1.0
        gap = float(np.linalg.norm(np.asarray(upper_lip)[:2] - np.asarray(lower_lip)[:2]))
        return float(np.round(min(1.0, gap / self._open_gap) * STEPS) / STEPS)

    def drawn(self, ratio: float) -> np.ndarray:
        """The open mouth's picture remapped for a mouth ``ratio`` as open (module docstring)."""
        if ratio >= 1.0:
            return self.image
        if self._cache[0] == ratio:
            return self._cache[1]
        y, top, bottom = self._rows, self._top, self._bottom
        inside = (y >= top) & (y <= bottom)
        upper = (y - top) <= (bottom - y)
        source = np.where(upper, top + (y - top) * ratio, bottom - (bottom - y) * ratio)
        source = np.where(inside, source, y)
        out = cv2.remap(self.image, self._cols, source.astype(np.float32), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)
        self._cache = (ratio, out)
        return out


def _curve(points: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """The y of a lip's loop (points (n, 2), corner to corner) at each column ``xs``, linear between
    its points and flat past its corners."""
    order = np.argsort(points[:, 0])
    return np.interp(xs, points[order, 0], points[order, 1])
