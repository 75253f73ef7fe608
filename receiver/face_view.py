"""Decoded parameters -> pixels: deform the base face, pose the head, render."""

import numpy as np

from codec.camera import Camera
from codec.deform import EXTENDED_PARAMS, Deformer
from codec.face_model import BaseFace
from codec.render import Renderer
from common.errors import BitstreamError
from protocol.stream import Header

FIELD_OF_VIEW = 20.0  # degrees: a portrait lens, little perspective distortion
FRAMING = 1.35  # the view's height over the face's height
BACKGROUND = (38, 42, 48)  # a dark slate that sets off skin without the harshness of black


def portrait_camera(face: BaseFace) -> Camera:
    """A perspective camera looking at the base face from the front, the face filling the view's height."""
    lo, hi = face.vertices.min(axis=0), face.vertices.max(axis=0)
    centre = (lo + hi) / 2
    distance = FRAMING * (hi[1] - lo[1]) / 2 / np.tan(np.radians(FIELD_OF_VIEW / 2)) + hi[2] - centre[2]
    return Camera.perspective(FIELD_OF_VIEW, eye=centre + [0, 0, distance], target=centre)


def face_renderer(face: BaseFace, size: tuple[int, int]) -> Renderer:
    """The receiver's look: the default lights and a dark mouth; a personal model (with a
    texture) shows its own eyes from the photo, the plain shaded face gets painted ones."""
    textured = face.texture is not None
    return Renderer(face.faces, size=size, mouth_faces=face.mouth_faces,
                    eye_faces=None if textured else face.eye_faces, background=BACKGROUND,
                    uv=face.uv if textured else None, texture=face.texture)


class FaceView:
    """Renders one (H, W, 3) uint8 RGB image per parameter vector of the stream's layout.

    A layout is any list of names from ``codec.deform.EXTENDED_PARAMS``; the
    parameters a stream leaves out stay at rest. ``check_id=False`` draws a
    face other than the one the stream names (the receiver's fallback when an
    in-band model was lost).
    """

    def __init__(self, header: Header, face: BaseFace, size: tuple[int, int], check_id: bool = True) -> None:
        if check_id and header.face_id != face.content_id:
            raise BitstreamError(f"the stream was made for face model {header.face_id[:12]}, "
                                 f"this receiver holds {face.content_id[:12]} (give the model with --face FILE)")
        unknown = [n for n in header.names if n not in EXTENDED_PARAMS]
        if unknown or len(set(header.names)) != len(header.names):
            raise BitstreamError(f"unknown parameter layout: {', '.join(header.names)}")
        self._slots = [EXTENDED_PARAMS.index(n) for n in header.names]
        self._f3_with_jaw = header.f3_with_jaw
        self._deformer = Deformer(face)
        self._renderer = face_renderer(face, size)
        self._camera = portrait_camera(face)

    def render(self, params: np.ndarray) -> np.ndarray:
        full = np.zeros(len(EXTENDED_PARAMS))
        full[self._slots] = params
        vertices = self._deformer.deform_extended(full, f3_with_jaw=self._f3_with_jaw)
        irises = self._deformer.iris(full)[0]
        return self._renderer.render(vertices, self._camera, irises)[0]
