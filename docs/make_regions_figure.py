"""Draw docs/regions.png (the region map), docs/presets.png (the paper's examples, by the paper's
rule) and docs/lip_rules.png (F3's weight, an opening jaw and a lip pressed into the chin under each
rule).

Orthographic views with cv2 line/polygon drawing only; run from anywhere:
    .venv/bin/python docs/make_regions_figure.py
"""

from __future__ import annotations

import colorsys
from pathlib import Path

import cv2
import numpy as np

from facedeform.codec.model.deform import PRESETS, Deformer
from facedeform.codec.model.face_model import load_base_face
from facedeform.codec.model.folds import Facing
from facedeform.codec.model.regions import FEATURE_NAMES

OUT = Path(__file__).resolve().parent
WHITE, BLACK, GREY = (255, 255, 255), (0, 0, 0), (150, 150, 150)
JAW_COLOUR = (40, 40, 200)  # BGR red
FIXED_COLOUR = (225, 225, 225)


def to_pixels(xy: np.ndarray, size: int, margin: float = 0.08) -> np.ndarray:
    """(k, 2) base-face coordinates (unit box around 0, y up) -> int pixel coordinates."""
    scale = size * (1 - 2 * margin)
    px = np.stack([size / 2 + xy[:, 0] * scale, size / 2 - xy[:, 1] * scale], axis=1)
    return np.round(px).astype(np.int32)


def region_colours(deformer: Deformer) -> list[tuple[int, int, int]]:
    """BGR per region: pale grey if its three points are fixed, hues for moving ones, red jaw."""
    points = deformer.face.meta["feature_points"].items()
    fixed = {FEATURE_NAMES.index(n) for n, fp in points if fp["role"] in ("fixed", "hinge")}
    tris = deformer.regions.triangles
    moving = [i for i, t in enumerate(tris) if not set(t) <= fixed]
    colours = []
    for i, _ in enumerate(deformer.regions.names):
        if i >= len(tris):
            colours.append(JAW_COLOUR)
        elif i in moving:
            h = moving.index(i) / len(moving)
            colours.append(tuple(int(255 * c) for c in colorsys.hsv_to_rgb(h, 0.45, 0.95))[::-1])
        else:
            colours.append(FIXED_COLOUR)
    return colours


def draw_regions(size: int = 900) -> np.ndarray:
    """Front view: triangles filled by the region of their vertices, feature triangles and labels."""
    face = load_base_face()
    d = Deformer(face)
    colours = region_colours(d)
    img = np.full((size + 90, size, 3), 255, np.uint8)
    px = to_pixels(face.vertices[:, :2], size)
    order = np.argsort(face.vertices[face.faces].mean(axis=1)[:, 2])  # back to front
    for f in face.faces[order]:
        regs = d.regions.region[f]
        reg = np.bincount(regs).argmax()
        cv2.fillConvexPoly(img, px[f], colours[reg], cv2.LINE_AA)
        cv2.polylines(img, [px[f]], True, GREY, 1, cv2.LINE_AA)
    fpx = px[[face.feature_points[n] for n in FEATURE_NAMES]]
    for t in d.regions.triangles:
        cv2.polylines(img, [fpx[t]], True, BLACK, 1, cv2.LINE_AA)
    for name, p in zip(FEATURE_NAMES, fpx):
        cv2.circle(img, tuple(int(v) for v in p), 5, BLACK, -1, cv2.LINE_AA)
        at = (int(p[0]) + 6, int(p[1]) - 6)
        cv2.putText(img, name, at, cv2.FONT_HERSHEY_SIMPLEX, 0.5, BLACK, 1, cv2.LINE_AA)
    o = d.regions.origin
    lines = [
        "grey: regions of fixed points (never move); colours: stretch regions; red: jaw regions (rigid)",
        "black: feature triangles (true borders: their central projections from O)",
        f"projection centre O = ({o[0]:g}, {o[1]:g}, {o[2]:g}), behind the face; jaw axis F12-F13",
    ]
    for k, text in enumerate(lines):
        cv2.putText(img, text, (10, size + 22 + 26 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.5, BLACK, 1, cv2.LINE_AA)
    return img


def wireframe(
    vertices: np.ndarray, faces: np.ndarray, mouth: np.ndarray, axes: tuple[int, int], size: int
) -> np.ndarray:
    """One orthographic wireframe panel (axes: which coordinates go right and up);
    mouth-interior triangles filled dark."""
    img = np.full((size, size, 3), 255, np.uint8)
    px = to_pixels(vertices[:, list(axes)], size)
    for f in faces[mouth]:
        cv2.fillConvexPoly(img, px[f], (60, 60, 60), cv2.LINE_AA)
    for f in faces:
        cv2.polylines(img, [px[f]], True, (90, 90, 90), 1, cv2.LINE_AA)
    return img


def draw_presets(size: int = 360) -> np.ndarray:
    """Front (top row) and side (bottom row) wireframes by the paper's rule: neutral, fig7, fig8, fig9."""
    face = load_base_face()
    d = Deformer(face, "paper")
    cols = []
    for name in ("neutral", "fig7", "fig8", "fig9"):
        params, f3_jaw = PRESETS[name]
        v = d.deform(params, f3_jaw)
        front = wireframe(v, face.faces, face.mouth_faces, (0, 1), size)
        side = wireframe(v, face.faces, face.mouth_faces, (2, 1), size)
        cv2.putText(front, name, (10, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.8, BLACK, 2, cv2.LINE_AA)
        cols.append(np.vstack([front, side]))
    return np.hstack(cols)


def lip_panel(vertices: np.ndarray, face, colour: np.ndarray, size: int, centre: float = -0.25,
              on_top: np.ndarray | None = None) -> np.ndarray:
    """Front close-up of the lower face about height ``centre``: triangles filled by ``colour`` (m, 3)
    BGR, back to front, those marked ``on_top`` last (folded skin hides under the rest)."""
    img = np.full((size, size, 3), 255, np.uint8)
    xy = (vertices[:, :2] - [0.0, centre]) * 2.6  # the mouth and chin fill the panel
    px = to_pixels(xy, size, margin=0.0)
    depth = vertices[face.faces].mean(axis=1)[:, 2] + (0.0 if on_top is None else 10.0 * on_top)
    for f in np.argsort(depth):
        cv2.fillConvexPoly(img, px[face.faces[f]], tuple(int(c) for c in colour[f]), cv2.LINE_AA)
        cv2.polylines(img, [px[face.faces[f]]], True, GREY, 1, cv2.LINE_AA)
    return img


#: A frame of liveportrait_d12 as fd-send fitted it (paper set) before it fitted around folds: the jaw
#: at 10.9 degrees, the lower lip 0.19 below where the jaw carries it, 0.03 above the chin.
PRESSED_LIP = np.array([10.872, 0.001, 0.001, 0.013, -0.0, -0.265, -0.095, 0.011, -0.093, -0.037, -0.006, -0.098,
                        -0.039])


def draw_lip_rules(size: int = 420, theta: float = 25.0) -> np.ndarray:
    """Per rule (top rows): F3's blend weight on the lower face (white 0 to blue 1), and the jaw
    opened by theta with F3 following it; bottom row, a lower lip sent into the chin under each rule.
    Mouth fill dark, flipped triangles red."""
    face = load_base_face()
    f3 = FEATURE_NAMES.index("F3")
    facing = Facing(face.vertices, face.faces)

    def shaded(vertices: np.ndarray, text: str, centre: float = -0.25) -> np.ndarray:
        flipped = facing.folded(vertices)
        shade = np.where(face.mouth_faces[:, None], 60, 235) * np.ones((1, 3))
        shade[flipped] = JAW_COLOUR
        return label(lip_panel(vertices, face, shade, size, centre, flipped), f"{text}, {flipped.sum()} flipped")

    rows, pressed = [], []
    for rule in ("paper", "refined"):
        d = Deformer(face, rule)
        w = d.regions.weights[face.faces, f3].mean(axis=1)
        weight = np.stack([255 - 55 * w, 255 - 200 * w, 255 - 200 * w], axis=1)  # BGR
        rows.append(np.hstack([label(lip_panel(face.vertices, face, weight, size), f"{rule}: weight of F3"),
                               shaded(d.deform(np.r_[theta, np.zeros(12)], True), f"{rule}: jaw {theta:g} deg")]))
        pressed.append(shaded(d.deform(PRESSED_LIP), f"{rule}: lip pressed", -0.36))
    return np.vstack(rows + [np.hstack(pressed)])


def label(img: np.ndarray, text: str) -> np.ndarray:
    cv2.putText(img, text, (10, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.7, BLACK, 2, cv2.LINE_AA)
    return img


def main() -> None:
    cv2.imwrite(str(OUT / "regions.png"), draw_regions())
    cv2.imwrite(str(OUT / "presets.png"), draw_presets())
    cv2.imwrite(str(OUT / "lip_rules.png"), draw_lip_rules())


if __name__ == "__main__":
    main()
