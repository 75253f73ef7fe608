"""Draw docs/regions.png (the region map) and docs/presets.png (the paper's examples).

Orthographic views with cv2 line/polygon drawing only; run from anywhere:
    .venv/bin/python docs/make_regions_figure.py
"""

from __future__ import annotations

import colorsys
from pathlib import Path

import cv2
import numpy as np

from codec.deform import PRESETS, Deformer
from codec.face_model import load_base_face
from codec.regions import FEATURE_NAMES

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
    """Front (top row) and side (bottom row) wireframes: neutral, fig7, fig8, fig9."""
    face = load_base_face()
    d = Deformer(face)
    cols = []
    for name in ("neutral", "fig7", "fig8", "fig9"):
        params, f3_jaw = PRESETS[name]
        v = d.deform(params, f3_jaw)
        front = wireframe(v, face.faces, face.mouth_faces, (0, 1), size)
        side = wireframe(v, face.faces, face.mouth_faces, (2, 1), size)
        cv2.putText(front, name, (10, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.8, BLACK, 2, cv2.LINE_AA)
        cols.append(np.vstack([front, side]))
    return np.hstack(cols)


def main() -> None:
    cv2.imwrite(str(OUT / "regions.png"), draw_regions())
    cv2.imwrite(str(OUT / "presets.png"), draw_presets())


if __name__ == "__main__":
    main()
