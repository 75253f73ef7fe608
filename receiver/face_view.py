"""Decoded parameters -> pixels: deform the base face, turn the head, render."""

import cv2
import numpy as np

from codec.camera import Camera
from codec.deform import PAPER_PARAMS, Deformer
from codec.errors import BitstreamError
from codec.face_model import BaseFace
from codec.render import Renderer
from protocol.stream import Header

HEAD_ROTATION = ("rx", "ry", "rz")
FIELD_OF_VIEW = 20.0  # degrees: a portrait lens, little perspective distortion
FRAMING = 1.35  # the view's height over the face's height
HEAD_DEPTH = 0.6  # the head turns about a point this far behind the face's centre (base-face units)
BACKGROUND = (38, 42, 48)  # a dark slate that sets off skin without the harshness of black


class FaceView:
    """Renders one (H, W, 3) uint8 RGB image per parameter vector of the stream's layout."""

    def __init__(self, header: Header, face: BaseFace, size: tuple[int, int]) -> None:
        if header.face_id != face.content_id:
            raise BitstreamError(f"the stream was made for face model {header.face_id[:12]}, "
                                 f"this receiver holds {face.content_id[:12]}")
        names = header.names
        if names[:len(PAPER_PARAMS)] != PAPER_PARAMS or names[len(PAPER_PARAMS):] not in ((), HEAD_ROTATION):
            raise BitstreamError(f"unknown parameter layout: {', '.join(names)}")
        self._turns_head = len(names) > len(PAPER_PARAMS)
        self._f3_with_jaw = header.f3_with_jaw
        self._deformer = Deformer(face)
        self._renderer = Renderer(face.faces, size=size, mouth_faces=face.mouth_faces, background=BACKGROUND)
        lo, hi = face.vertices.min(axis=0), face.vertices.max(axis=0)
        centre = (lo + hi) / 2
        distance = FRAMING * (hi[1] - lo[1]) / 2 / np.tan(np.radians(FIELD_OF_VIEW / 2)) + hi[2] - centre[2]
        self._camera = Camera.perspective(FIELD_OF_VIEW, eye=centre + [0, 0, distance], target=centre)
        self._pivot = centre - [0, 0, HEAD_DEPTH]

    def render(self, params: np.ndarray) -> np.ndarray:
        vertices = self._deformer.deform(params[:len(PAPER_PARAMS)], f3_with_jaw=self._f3_with_jaw)
        if self._turns_head:
            rotation, _ = cv2.Rodrigues(np.radians(params[len(PAPER_PARAMS):]))
            vertices = (vertices - self._pivot) @ rotation.T + self._pivot
        return self._renderer.render(vertices, self._camera)[0]
