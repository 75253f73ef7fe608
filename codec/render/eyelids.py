"""Closed lids in the whole picture: skin over the eye as the lids meet.

The picture view draws the face by warping the reference picture, whose eyes
are open. Lids that meet in the deformed mesh then only squash the open eye
(iris and white) into a dark slit, which neither looks nor tracks as a closed
eye: on the dev clips where the speaker blinks, the tracker saw the oracle's
warped blinks with an eye-opening correlation of only 0.74-0.78. Here each
eye's opening and a band around it (EDGE of the eye's width) is filled with the
skin just below it, with a line of lashes where the lids meet, and as the lids
close the texture there crossfades to that skin, from CLOSING to CLOSED of the
lid gap's closure; the mesh carries it, so a closed eye shows lid skin where
the eye was. Below CLOSING the lid slides over the eye instead: the eye's lower
part keeps its own scale where the mesh squashes the opening, so lids lowered
over eyes that look down cover the irises' tops. Where enrolment saw the speaker blink, the face
file carries their own shut eyes (sender/enrolment.ShutEyes) and the eye crossfades to them instead
of the skin below it. The sender sends the lids as
far closed as they are, not as far as the tracker says (sender/fit.LID_GAIN).
Both ends compute it from the same picture, so the
sender's closed loop draws what the receiver draws.
"""

from __future__ import annotations

import cv2
import numpy as np

from facedeform.codec.model.face_model import BaseFace

#: Upper and lower lid middles and the corners of each eye (face-right, face-left): landmark indices.
LIDS = ((159, 145), (386, 374))
CORNERS = ((33, 133), (362, 263))
LOOPS = ("eye_right", "eye_left")
#: The lid gap's closure (0 open as at rest, 1 shut) where the skin starts showing and where it has replaced the eye.
CLOSING, CLOSED = 0.7, 0.95
#: The crossfade moves in these steps, so that a still eye does not retexture the scene every frame.
STEPS = 8
EDGE = 0.15  # the band around the opening that is filled too (lashes, the lid's edge), over the eye's width
BELOW = 2  # pixels below an eye's filled band that its lid skin is taken from
LASH = 0.06  # the shut lids' line, drawn in the darkest tenth of the eye's colours, over the eye's width
LASH_BITS = 4  # its points' fractional bits (OpenCV's shift), for a line placed to the subpixel
LASH_SHIFT = 1 << LASH_BITS
MARGIN = 8  # pixels around the eyes' bands in the box the lids change: the skin below, the blur


class Eyelids:
    """For one face and its reference picture's pixels of the face vertices at rest ``pixels`` (n, 2);
    with the picture's ``shut_eyes`` (ReferencePicture), where they cover both eyes' :attr:`box`."""

    def __init__(self, face: BaseFace, pixels: np.ndarray, size: tuple[int, int]) -> None:
        rest = np.asarray(face.vertices, dtype=np.float64)
        self._rest_gap = np.array([np.linalg.norm(rest[a] - rest[b]) for a, b in LIDS])
        width, height = size
        openings, masks, lashes = [], [], []
        for loop, (a, b) in zip(LOOPS, CORNERS):
            ring = face.meta["loops"][loop]  # outer corner, upper lid, inner corner (index 8), lower lid
            opening = np.zeros((height, width), np.uint8)
            cv2.fillPoly(opening, [np.round(pixels[ring]).astype(np.int32)], 255)
            openings.append(opening)
            eye_width = float(np.linalg.norm(pixels[a] - pixels[b]))
            grow = max(1, int(round(EDGE * eye_width)))
            masks.append(cv2.dilate(opening, np.ones((2 * grow + 1, 2 * grow + 1), np.uint8)))
            lashes.append((pixels[ring[8:] + ring[:1]], max(1, int(round(LASH * eye_width)))))  # the lower lid
        # everything happens in one box around both eyes: a frame whose lids move changes only it
        ys, xs = np.nonzero(np.maximum(*masks))
        x0, y0 = max(0, xs.min() - MARGIN), max(0, ys.min() - MARGIN)
        x1, y1 = min(width, xs.max() + 1 + MARGIN), min(height, ys.max() + 1 + MARGIN)
        self.box = (x0, y0, x1, y1)
        self._openings = [_Opening(m[y0:y1, x0:x1]) for m in openings]
        self._masks = [m[y0:y1, x0:x1] for m in masks]
        self._lashes = [(np.round((line - [x0, y0]) * LASH_SHIFT).astype(np.int32), thick) for line, thick in lashes]
        self._soft = [cv2.GaussianBlur(m, (0, 0), 1.0).astype(np.float32)[..., None] / 255 for m in self._masks]
        self._skin: np.ndarray | None = None  # the box with both eyes filled, for the picture self._of
        self._of: np.ndarray | None = None
        self._own = _own_shut(face.picture, self.box)  # the speaker's own shut eyes in the box, or None

    def weights(self, deformed: np.ndarray) -> tuple[float, ...]:
        """How far each eye (face-right, face-left) is closed, 0 (as at rest or wider) to 1 (shut) in
        1/STEPS, for a pose-free deformed face (468+, 3)."""
        gap = np.array([np.linalg.norm(deformed[a] - deformed[b]) for a, b in LIDS])
        closure = np.clip(1.0 - gap / np.maximum(self._rest_gap, 1e-9), 0.0, 1.0)
        return tuple(float(x) for x in np.round(closure * STEPS) / STEPS)

    def apply(self, picture: np.ndarray, closures: tuple[float, ...]) -> np.ndarray:
        """``picture`` (the reference picture, or it renewed) with each eye as far closed as given
        (:meth:`region` in :attr:`box`)."""
        if not any(closures):
            return picture
        x0, y0, x1, y1 = self.box
        out = picture.copy()
        out[y0:y1, x0:x1] = self.region(picture, closures)
        return out

    def region(self, picture: np.ndarray, closures: tuple[float, ...]) -> np.ndarray:
        """The :attr:`box` of ``picture`` with each eye as far closed as given: the lid slides over
        it (the eye's lower part keeps its own scale where the mesh squashes the opening), and
        past CLOSING the eye crossfades to skin."""
        x0, y0, x1, y1 = self.box
        crop = picture[y0:y1, x0:x1]
        out = crop.copy()
        for opening, closure in zip(self._openings, closures):
            opening.slide(crop, out, closure)
        weights = [float(np.clip((c - CLOSING) / (CLOSED - CLOSING), 0.0, 1.0)) for c in closures]
        if not any(weights):
            return out
        skin = self._own if self._own is not None else self._drawn_skin(picture, crop)
        blend = sum(w * soft for w, soft in zip(weights, self._soft))
        return np.clip(np.rint(out + blend * (skin.astype(np.float32) - out)), 0, 255).astype(np.uint8)

    def _drawn_skin(self, picture: np.ndarray, crop: np.ndarray) -> np.ndarray:
        """The box ``crop`` of ``picture`` with both eyes filled by skin and a line of lashes, kept
        while the picture is the same."""
        if self._skin is None or self._of is not picture:
            self._skin = skin = _lid_skin(crop, self._masks)
            for mask, (line, thickness) in zip(self._masks, self._lashes):
                dark = np.percentile(crop[mask > 0], 10, axis=0)  # the lashes' colour
                cv2.polylines(skin, [line], False, [float(c) for c in dark], thickness, cv2.LINE_AA, LASH_BITS)
            self._of = picture
        return self._skin


class _Opening:
    """One eye's opening in the picture, for sliding its lid: per column, the opening's top and
    bottom rows."""

    def __init__(self, mask: np.ndarray) -> None:
        ys, xs, bottom = _lowest_rows(mask)
        self._x0, self._x1, self._y0, self._y1 = xs.min(), xs.max() + 1, ys.min(), ys.max() + 1
        self._inside = mask[self._y0:self._y1, self._x0:self._x1] > 0
        self._bottom = bottom[self._x0:self._x1].astype(np.float32)
        self._rows, self._cols = np.mgrid[self._y0:self._y1, self._x0:self._x1].astype(np.float32)

    def slide(self, picture: np.ndarray, out: np.ndarray, closure: float) -> None:
        """Writes into ``out`` the opening as the mesh will squash it to (1 - closure) of its height:
        each column's lower (1 - closure) of the eye, stretched to the whole opening."""
        if closure <= 0:
            return
        source_y = self._bottom - (self._bottom - self._rows) * (1.0 - closure)
        moved = cv2.remap(picture, self._cols, source_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        region = out[self._y0:self._y1, self._x0:self._x1]
        region[self._inside] = moved[self._inside]


def _own_shut(picture, box: tuple[int, int, int, int]) -> np.ndarray | None:
    """``picture``'s shut eyes (ReferencePicture.shut_eyes) cut to ``box``, or None where it has none
    or they do not cover it (a face file written for another picture)."""
    if picture is None or picture.shut_eyes is None or picture.shut_eyes_at is None:
        return None
    (x, y), (x0, y0, x1, y1) = picture.shut_eyes_at, box
    height, width = picture.shut_eyes.shape[:2]
    if not (x <= x0 and y <= y0 and x1 <= x + width and y1 <= y + height):
        return None
    return np.ascontiguousarray(picture.shut_eyes[y0 - y:y1 - y, x0 - x:x1 - x])


def _lid_skin(picture: np.ndarray, masks: list[np.ndarray]) -> np.ndarray:
    """``picture`` with each eye's ``mask`` filled by the skin just below it, column by column, and
    smoothed along the eye: a shut lid looks like the skin under the eye, while the skin above it
    reaches the brows (inpainting from the whole rim smeared them down over the eye)."""
    out = picture.copy()
    height = picture.shape[0]
    for mask in masks:
        ys, xs, lowest = _lowest_rows(mask)
        out[ys, xs] = picture[np.minimum(lowest[xs] + BELOW, height - 1), xs]
        x0, x1, y0, y1 = xs.min(), xs.max() + 1, ys.min(), ys.max() + 1
        smooth = cv2.GaussianBlur(out[y0:y1, x0:x1], (0, 0), sigmaX=2.0, sigmaY=0.5)
        inside = mask[y0:y1, x0:x1] > 0
        out[y0:y1, x0:x1][inside] = smooth[inside]
    return out


def _lowest_rows(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rows, columns) of ``mask``'s pixels and, per column of the mask, its lowest such row (-1: none)."""
    ys, xs = np.nonzero(mask)
    lowest = np.full(mask.shape[1], -1)
    np.maximum.at(lowest, xs, ys)
    return ys, xs, lowest
