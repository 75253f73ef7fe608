"""Draw docs/presets_rendered.png (the paper's Figs. 6-9, shaded) and docs/expressions.png.

The presets are drawn by the paper's rule (top row) and, for comparison, by the
project's refined rule (bottom row, codec/model/regions.py); the expressions by the
refined rule, as fd-animate draws them. Rendered with codec.render.render.Renderer
through the receiver's perspective camera (receiver/face_view.py framing); run
from anywhere:
    .venv/bin/python docs/make_preset_renders.py
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from facedeform.codec.model.deform import PRESETS, Deformer
from facedeform.codec.model.expressions import expression_params
from facedeform.codec.model.face_model import load_base_face
from facedeform.codec.render.render import Renderer
from facedeform.receiver.face_view import portrait_camera

OUT = Path(__file__).resolve().parent
SIZE = 360
PRESET_TITLES = {"neutral": "Fig. 6 neutral", "fig7": "Fig. 7", "fig8": "Fig. 8", "fig9": "Fig. 9"}
EXPRESSIONS = ("neutral", "smile", "surprise", "blink", "AA", "OO", "anger", "sadness")


def label(image: np.ndarray, text: str) -> np.ndarray:
    """RGB image with a white caption in its top-left corner."""
    out = image.copy()
    cv2.putText(out, text, (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 255, 255), 2, cv2.LINE_AA)
    return out


def main() -> None:
    face = load_base_face()
    renderer = Renderer(face.faces, size=(SIZE, SIZE), mouth_faces=face.mouth_faces,
                        eye_faces=face.eye_faces, supersample=2)
    camera = portrait_camera(face)
    deformers = {rule: Deformer(face, rule) for rule in ("paper", "refined")}
    rows = [np.hstack([label(renderer.render(d.deform(*PRESETS[n]), camera)[0], f"{t}, {rule}")
                       for n, t in PRESET_TITLES.items()]) for rule, d in deformers.items()]
    tiles = []
    for name in EXPRESSIONS:
        params = expression_params(name)
        tiles.append(label(renderer.render(deformers["refined"].deform_extended(params), camera)[0], name))
    grid = np.vstack([np.hstack(tiles[:4]), np.hstack(tiles[4:])])
    cv2.imwrite(str(OUT / "presets_rendered.png"), cv2.cvtColor(np.vstack(rows), cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(OUT / "expressions.png"), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR))


if __name__ == "__main__":
    main()
