"""Render a deformed face mesh to an sRGB image with per-pixel (Phong) shading.

Shading happens in linear light: colour = albedo * (ambient + sum of light *
max(n.l, 0)) + specular * sum of light * max(n.h, 0) ** shininess
(Blinn-Phong), encoded to sRGB at the end. Lighting is double-sided: the
interpolated normal is flipped toward the viewer, and nothing is culled.
The half vector h uses one view direction per frame, from the mesh's centre
to the eye: under a portrait lens (the receiver's 20 degrees) the true
per-pixel one differs by under 10 degrees, shifting highlights by under 5,
and it saves two square roots per pixel and light.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from facedeform.common.limits import MAX_SIDE

from .camera import Camera
from .face_parts import eye_components, eye_discs, eye_pieces, teeth_columns
from .raster import EYE, MOUTH, SKIN, SPEC_STEPS, draw, resolve


def srgb_to_linear(values) -> np.ndarray:
    """sRGB-encoded values in [0, 1] -> linear light, float64, same shape."""
    v = np.asarray(values, dtype=np.float64)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(values) -> np.ndarray:
    """Linear light in [0, 1] -> sRGB-encoded values in [0, 1], float64, same shape."""
    v = np.clip(np.asarray(values, dtype=np.float64), 0.0, 1.0)
    return np.where(v <= 0.0031308, v * 12.92, 1.055 * v ** (1 / 2.4) - 0.055)


_DECODE = srgb_to_linear(np.arange(256) / 255.0)
_NO_IRISES = np.zeros((0, 3))
_NO_DEPTH = np.zeros((0, 0), np.float32)  # Renderer.image: no depth kept
_ENCODE = np.round(linear_to_srgb(np.arange(65536) / 65535.0) * 255.0).astype(np.uint8)


@dataclass(frozen=True)
class Material:
    """Surface reflectance; albedo is linear RGB in [0, 1] (default: a skin tone)."""

    albedo: tuple[float, float, float] = (0.70, 0.42, 0.32)
    ambient: float = 0.18
    specular: float = 0.12
    shininess: float = 24.0


@dataclass(frozen=True)
class DirectionalLight:
    """A light at infinity; direction points from the surface toward the light (world)."""

    direction: tuple[float, float, float]
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    intensity: float = 1.0


UNLIT = Material(ambient=1.0, specular=0.0)  # a texture's own light, as a picture shows it
KEY_LIGHT = DirectionalLight((-0.4, 0.5, 1.0), intensity=0.85)
FILL_LIGHT = DirectionalLight((0.7, -0.1, 0.5), intensity=0.3)


def _finite(value, shape, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != shape or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite with shape {shape}, got {np.shape(value)}")
    return arr


def _lights(lights) -> tuple[np.ndarray, tuple]:
    """(k, 3) float64 unit directions and k (r, g, b) tuples of colour * intensity.

    The colours are a tuple, not an array, so that numba compiles the shading
    for k lights with its loop over them unrolled (about 6 % faster). No
    lights become one black light, which adds exactly nothing: numba cannot
    index an empty tuple.
    """
    dirs, rgbs = [], []
    for light in lights:
        d = _finite(light.direction, (3,), "light direction")
        if not np.linalg.norm(d) > 0.0:
            raise ValueError("light direction must be non-zero")
        dirs.append(d / np.linalg.norm(d))
        rgbs.append(tuple((_finite(light.color, (3,), "light color") * float(light.intensity)).tolist()))
    if not lights:
        dirs, rgbs = [(0.0, 0.0, 1.0)], [(0.0, 0.0, 0.0)]
    return np.array(dirs, dtype=np.float64), tuple(rgbs)


class Renderer:
    """Rasterises one triangle mesh topology, frame after frame.

    faces: (m, 3) int vertex indices; size: (width, height) of the output;
    uv: (n, 2) texture coordinates in [0, 1] with v up (v = 0 is the bottom
    row of texture), used with texture: (h, w, 3) uint8 RGB, which replaces
    the albedo; mouth_faces: (m,) bool marking the mouth interior, drawn dark
    with a band of teeth under its upper edge; eye_faces: (m,) bool marking
    the eye fills, drawn as sclera with a dark iris and pupil at each eye's
    centre (one eye per connected piece); supersample: 1, or 2 for 2x2
    anti-aliasing. Buffers are reused between frames: one instance is not
    thread-safe.
    """

    def __init__(self, faces, size=(512, 512), material: Material = Material(),
                 lights=(KEY_LIGHT, FILL_LIGHT), background=(0, 0, 0), uv=None,
                 texture=None, mouth_faces=None, supersample: int = 1, eye_faces=None):
        faces = np.asarray(faces)
        if faces.ndim != 2 or faces.shape[1] != 3 or faces.shape[0] == 0 \
                or not np.issubdtype(faces.dtype, np.integer) or faces.min() < 0:
            raise ValueError(f"faces must be a non-empty (m, 3) array of non-negative ints, "
                             f"got {faces.dtype} {faces.shape}")
        self.faces = np.array(faces, dtype=np.int32, order="C")  # its own: set_faces changes it
        self._min_vertices = int(faces.max()) + 1
        width, height = (int(s) for s in size)
        if not (0 < width <= MAX_SIDE and 0 < height <= MAX_SIDE):
            raise ValueError(f"size must be (width, height) in 1..{MAX_SIDE}, got {size}")
        self.size = (width, height)
        if supersample not in (1, 2):
            raise ValueError(f"supersample must be 1 or 2, got {supersample}")
        self.supersample = supersample
        self.material = material
        self._albedo = _finite(material.albedo, (3,), "material albedo")
        ambient, specular, shininess = _finite(
            (material.ambient, material.specular, material.shininess), (3,),
            "material ambient/specular/shininess")
        if shininess <= 0.0:
            raise ValueError(f"material shininess must be positive, got {material.shininess}")
        self._ambient = float(ambient)
        spec = specular * (np.arange(SPEC_STEPS + 2) / SPEC_STEPS) ** shininess
        self._spec_lut = np.stack([spec[:-1], np.diff(spec)], axis=1)  # value and slope per interval
        # below this n.h the highlight adds under 1e-5 (a 1/65536 encoder step)
        self._spec_cut = (1e-5 / specular) ** (1.0 / shininess) if specular > 0.0 else 2.0
        self._light_dir, self._light_rgb = _lights(tuple(lights))
        self._flat = not lights  # ambient light alone: no normals to interpolate, nothing to light
        # a texture drawn as it is (a picture's own light, one sample a pixel) is sampled by an image
        # warp, in its own sRGB encoding (codec/render/raster.py, maps): a quarter of the memory, no conversions
        self._own = self._flat and ambient == 1.0 and supersample == 1 and texture is not None
        self._background = self._parse_background(background)
        self._uv, self._texture = self._parse_texture(uv, texture)
        mouth, eyes = (self._mask(m, name) for m, name in ((mouth_faces, "mouth_faces"),
                                                           (eye_faces, "eye_faces")))
        if (mouth & eyes).any():
            raise ValueError("mouth_faces and eye_faces overlap")
        self._mouth_vertices = np.unique(self.faces[mouth])
        self._eyes = eye_components(self.faces, eyes)
        if len(self._eyes) > 127 - EYE:
            raise ValueError(f"eye_faces has {len(self._eyes)} separate pieces, at most {127 - EYE}")
        self._eye_pieces = eye_pieces(self.faces, self._eyes)
        self._kind = np.zeros(len(self.faces), np.int8)
        self._kind[mouth] = MOUTH
        for e, tris in enumerate(self._eyes):
            self._kind[tris] = EYE + e
        shape = (height * supersample, width * supersample)
        self._nearness = np.full(shape, -np.inf, np.float32)
        # 2x2 samples are shaded into linear RGB and resolved; one sample per pixel goes straight out
        self._linear = np.zeros((*shape, 3) if supersample > 1 else (0, 0, 3), np.float32)
        self._drawn = (0, 0, -1, -1)  # the last frame's drawn box, to clear
        self._no_count = np.zeros((0, 0), np.int32)
        self._maps = np.zeros((*shape, 2) if self._own else (0, 0, 2), np.int16)  # whole texels x, y (raster.draw)
        self._fractions = np.zeros(shape if self._own else (0, 0), np.uint16)  # and their fractions
        self._warped = np.zeros(shape if self._own else (0, 0), np.uint8)

    def _mask(self, mask, name: str) -> np.ndarray:
        if mask is None:
            return np.zeros(len(self.faces), bool)
        mask = np.asarray(mask)
        if mask.shape != (len(self.faces),) or mask.dtype != bool:
            raise ValueError(f"{name} must be a bool mask of shape ({len(self.faces)},)")
        return mask

    def patch_texture(self, x: int, y: int, image: np.ndarray) -> None:
        """Replace the texture's pixels from column ``x``, row ``y`` (from the top) by ``image``
        ((h, w, 3) uint8, inside the texture): a part that changes often (the open mouth), without
        converting the whole texture again."""
        h, w = image.shape[:2]
        height, width = self._texture.shape[0] - self._own, self._texture.shape[1] - self._own
        if not (0 <= x and 0 <= y and y + h <= height and x + w <= width):
            raise ValueError(f"a {w}x{h} patch at ({x}, {y}) is outside the texture")
        if not self._own:
            self._texture[y:y + h, x:x + w] = _DECODE[image]
            return
        self._texture[y:y + h, x:x + w] = image
        self._texture[:, -1], self._texture[-1] = self._texture[:, -2], self._texture[-2]  # the repeats

    def retexture(self, uv, texture) -> None:
        """Texture the mesh by ``texture`` at ``uv`` from the next frame on, as the constructor's (a
        mesh textured by a picture that changes: the picture layer's video, carried by the face)."""
        if texture is None:
            raise ValueError("retexture needs a texture")
        self._uv, self._texture = self._parse_texture(uv, texture)

    def set_faces(self, index, faces, mouth) -> None:
        """Draw faces ``index`` as ``faces`` (k, 3) from the next frame on, each the mouth's interior where
        ``mouth`` (k,) and skin elsewhere (a part drawn one way or another frame by frame: the mouth
        opening's slivers, codec/render/picture.SceneMesh.slivers). Eye faces stay as they are."""
        index, faces = np.asarray(index, dtype=np.int64), np.asarray(faces)
        mouth = np.asarray(mouth, dtype=bool)
        if faces.shape != (len(index), 3) or mouth.shape != index.shape or not np.issubdtype(faces.dtype, np.integer):
            raise ValueError(f"faces must be ({len(index)}, 3) ints with a mouth flag each, got {faces.shape}")
        if len(index) and (index.min() < 0 or index.max() >= len(self.faces) or (self._kind[index] >= EYE).any()):
            raise ValueError("index must name faces of the mesh that are not an eye's")
        if len(faces) and (faces.min() < 0 or faces.max() >= self._min_vertices):
            raise ValueError(f"faces' vertices must be in 0..{self._min_vertices - 1}")
        self.faces[index] = faces
        self._kind[index] = np.where(mouth, MOUTH, SKIN)

    def set_background(self, background) -> None:
        """Draw over ``background`` from the next frame on: as the constructor's (a moving camera's picture)."""
        self._background = self._parse_background(background)

    def _parse_background(self, background) -> np.ndarray:
        width, height = self.size
        if isinstance(background, np.ndarray) and background.ndim == 3:
            if background.shape != (height, width, 3) or background.dtype != np.uint8:
                raise ValueError(f"background image must be ({height}, {width}, 3) uint8, "
                                 f"got {background.dtype} {background.shape}")
            return np.ascontiguousarray(background)
        rgb = np.asarray(background)
        if rgb.shape != (3,) or not np.all((rgb >= 0) & (rgb <= 255)):
            raise ValueError(f"background must be an (r, g, b) tuple in 0..255 or an image, "
                             f"got {background!r}")
        return np.ascontiguousarray(np.broadcast_to(rgb.astype(np.uint8), (height, width, 3)))

    def _parse_texture(self, uv, texture) -> tuple[np.ndarray, np.ndarray]:
        if (uv is None) != (texture is None):
            raise ValueError("uv and texture must be given together")
        if texture is None:
            return np.zeros((0, 2)), np.zeros((0, 0, 3), np.float32)
        uv = np.asarray(uv, dtype=np.float64)
        if uv.ndim != 2 or uv.shape[1] != 2 or uv.shape[0] < self._min_vertices \
                or not np.all(np.isfinite(uv)):
            raise ValueError(f"uv must be finite (n, 2) with n >= {self._min_vertices}, "
                             f"got {uv.shape}")
        texture = np.asarray(texture)
        if texture.ndim != 3 or texture.shape[2] != 3 or texture.dtype != np.uint8 \
                or texture.shape[0] == 0 or texture.shape[1] == 0:
            raise ValueError(f"texture must be (h, w, 3) uint8, got {texture.dtype} {texture.shape}")
        if self._own:  # the last column and row once more: a lookup's second taps there (raster.draw, maps)
            return np.ascontiguousarray(uv), cv2.copyMakeBorder(texture, 0, 1, 0, 1, cv2.BORDER_REPLICATE)
        return np.ascontiguousarray(uv), _DECODE[texture].astype(np.float32)

    def render(self, vertices, camera: Camera, irises=None) -> tuple[np.ndarray, np.ndarray]:
        """Draw the mesh posed at vertices: (n, 3) world positions.

        irises: optional (k, 3) iris centres (e.g. from a gaze model); each eye
        takes the nearest one instead of the midpoint of its corners.

        Returns image (H, W, 3) uint8 sRGB and depth (H, W) float32: distance
        along the camera's viewing axis of the nearest surface (the nearest of
        the 2x2 samples when supersampling), +inf where nothing is drawn.
        """
        return self._render(vertices, camera, irises, self._no_count)

    def image(self, vertices, camera: Camera, irises=None) -> np.ndarray:
        """:meth:`render`'s image alone, without keeping a depth buffer (which the pictures the
        receiver draws never read: at 1080p a 8 MB fill and a write per pixel saved)."""
        return self._render(vertices, camera, irises, self._no_count, keep_depth=False)[0]

    def _render(self, vertices, camera: Camera, irises, count,
                keep_depth: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """render(), also counting every fragment into count (sH, sW) int32 unless it is (0, 0)."""
        v = np.asarray(vertices)
        if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] < self._min_vertices:
            raise ValueError(f"vertices must be (n, 3) with n >= {self._min_vertices}, got {v.shape}")
        v = np.ascontiguousarray(v, dtype=np.float64)
        if not np.all(np.isfinite(v)):
            raise ValueError("vertices contain NaN or infinite values")
        if len(self._uv) and len(self._uv) != len(v):
            raise ValueError(f"vertices must match uv: {len(self._uv)} rows, got {len(v)}")
        if not isinstance(camera, Camera):
            raise ValueError(f"camera must be a Camera, got {type(camera).__name__}")
        irises = _NO_IRISES if irises is None else _finite(irises, np.shape(irises), "irises")
        if irises.ndim != 2 or irises.shape[1] != 3:
            raise ValueError(f"irises must be (k, 3), got {irises.shape}")
        ss = self.supersample
        width, height = self.size
        sw, sh = width * ss, height * ss
        screen = camera.project(v, (sw, sh))
        persp = camera.is_perspective
        image = self._background.copy()
        depth = np.full((height, width), np.inf, np.float32) if keep_depth else _NO_DEPTH
        shading = (self._ambient, self._albedo, self._light_dir, self._light_rgb, self._spec_lut,
                   self._spec_cut, self._flat)
        view = (camera.basis(), camera.eye, 1.0 / camera.focal(sh) if persp else 0.0)
        box = draw(screen, persp, v, self._uv, self.faces, self._kind, camera.near, camera.far,
                   self._drawn, self._nearness, count, shading, view, self._texture,
                   teeth_columns(screen, self._mouth_vertices, sw),
                   eye_discs(v, self.faces, *self._eye_pieces, irises), _ENCODE, image, depth,
                   self._linear, self._maps, self._fractions, self._warped)
        self._drawn = box
        if self._own and box[0] <= box[2]:  # (remap's BORDER_TRANSPARENT, which would save the copy,
            # writes to some 3-channel pixels it should leave, differently by thread count)
            rows, columns = slice(box[1], box[3] + 1), slice(box[0], box[2] + 1)
            warped = cv2.remap(self._texture, self._maps[rows, columns], self._fractions[rows, columns],
                               cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            cv2.copyTo(warped, self._warped[rows, columns], image[rows, columns])
        if ss > 1 and box[0] <= box[2]:
            resolve(self._nearness, self._linear, box, persp, self._background, _DECODE, _ENCODE,
                    image, depth)
        return image, depth


#: What :func:`warm_up` does when it is slow: the first time after an install (19.4 s measured on the
#: development machine, 16.5 of it the rasteriser's, 0.7 s once cached), numba compiles the rasteriser
#: and the picture layer's kernels.
WARMING_UP = "preparing the renderer's machine code (once after an install: 15-30 s)"


def warm_up() -> None:
    """Loads (or compiles) the rasteriser's machine code by drawing one small triangle: a live
    receiver does this while it waits for the call, not when the first frame is due."""
    triangle = np.array([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.0, 0.5, 0.0]])
    camera = Camera.orthographic(2.0, eye=(0.0, 0.0, 2.0), target=(0.0, 0.0, 0.0))
    Renderer(np.array([[0, 1, 2]]), size=(8, 8)).render(triangle, camera)
    # and the whole picture's: a texture drawn as it is (a machine code of its own)
    Renderer(np.array([[0, 1, 2]]), size=(8, 8), material=UNLIT, lights=(), uv=triangle[:, :2] + 0.5,
             texture=np.zeros((2, 2, 3), np.uint8)).render(triangle, camera)
    # and the picture layer's, which would otherwise stall the first frame a layer packet reaches
    from facedeform.codec.render.frame_video import (
        blend,
        blocks_of,
        choose_payload,
        decode_blocks,
        encode_blocks,
        video_parts,
    )

    picture = np.zeros((64, 64, 3), np.uint8)
    parts = video_parts(picture, picture[::2, ::2])
    chosen = np.zeros(blocks_of((64, 64)), bool)
    blend(parts, choose_payload(parts, picture, picture, chosen)[0], (64, 64))
    decode_blocks(chosen, encode_blocks(chosen, chosen))
