"""The pre-shared base face: MediaPipe's canonical face mesh in base-face units.

Vertex ``i`` of the mesh is landmark ``i`` of the 468-point face-mesh tracker, so
feature points, lip and eye loops are plain landmark indices (read from
``feature_points.json`` next to the mesh).

Base-face units follow the paper: the face fits in about a unit box. The
canonical mesh (centimetres) is scaled so that the height from the forehead top
(landmark 10) to the chin bottom (landmark 152) is exactly 1, and shifted so
that the centre of its axis-aligned bounding box is the origin. Axes: x toward
the face's own left (landmark 263, the subject's left eye, has x > 0), y up,
z toward the viewer; the canonical mesh already uses these directions.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facedeform.codec.data import data_path
from facedeform.codec.model.motion_basis import MotionBasis
from facedeform.common.errors import InputError

DEFAULT_DIR = data_path("")
MESH_FILE = "canonical_face.pbtxt"
FEATURES_FILE = "feature_points.json"
N_LANDMARKS = 468
TOP, CHIN = 10, 152  # forehead top and chin bottom: the unit of height


@dataclass(frozen=True, eq=False)
class BaseFace:
    """A face mesh whose vertex i is tracker landmark i.

    vertices (468, 3) float64 base-face units; faces (m, 3) int32; uv (468, 2)
    float64 texture coordinates with v up, as the renderer takes them (the
    canonical file stores v down), so texture images stand upright; feature_points "F1".."F15" -> landmark index;
    mouth_faces / eye_faces (m,) bool mark the triangles filling the mouth
    opening and the eyes; content_id is the sha256 hex that names the model in
    the stream header; meta is the parsed feature_points.json (regions, O);
    texture (h, w, 3) uint8 RGB or None: a person's own skin (codec/face_file/format.py),
    None for the generic face, which the renderer shades in a plain material;
    motion: the person's own motion basis (codec/model/motion_basis.py) or None;
    picture: the person's whole reference picture and where the face sits in it (codec/render/picture.py), or None.
    """

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    feature_points: dict[str, int]
    mouth_faces: np.ndarray
    eye_faces: np.ndarray
    content_id: str
    meta: dict
    texture: np.ndarray | None = None
    motion: MotionBasis | None = None
    picture: ReferencePicture | None = None


@dataclass(frozen=True, eq=False)
class ReferencePicture:
    """image (H, W, 3) uint8 RGB: a whole frame of the person; projection (3, 4) float64: homogeneous
    model points to (pixel x, pixel y down, depth toward the viewer) in it, a similarity; mouth
    (h, w, 3) uint8 RGB or None: their open mouth, from another frame, and mouth_points (k, 2)
    float64: where the vertices of the mouth opening (``mouth_vertices``) are in it, in pixels;
    ring_weights (rings x boundary,) float64 in 0..1 or None: how far each vertex of the receiver's
    rings around the face follows the head (codec/render/picture.SceneMesh), as enrolment measured it;
    shut_eyes (h, w, 3) uint8 RGB or None: the person's eyes shut, from a blink, moved onto this
    picture's eyes (codec/render/eyelids.py), whose top-left pixel in it is shut_eyes_at (x, y)."""

    image: np.ndarray
    projection: np.ndarray
    mouth: np.ndarray | None = None
    mouth_points: np.ndarray | None = None
    ring_weights: np.ndarray | None = None
    shut_eyes: np.ndarray | None = None
    shut_eyes_at: tuple[int, int] | None = None


def mouth_vertices(face: BaseFace) -> np.ndarray:
    """(k,) sorted indices of the vertices of the triangles filling the mouth opening."""
    return np.unique(face.faces[face.mouth_faces])


def content_id(vertices: np.ndarray, faces: np.ndarray, meta: dict) -> str:
    """sha256 hex of the canonical bytes: '<f8' vertices, '<i4' faces, and the sorted-key JSON of
    the feature points, regions and O, since all of them shape the deformation."""
    h = hashlib.sha256(b"facedeform/base-face/v1\0")
    h.update(np.ascontiguousarray(vertices, dtype="<f8").tobytes())
    h.update(np.ascontiguousarray(faces, dtype="<i4").tobytes())
    h.update(json.dumps(meta, sort_keys=True, separators=(",", ":")).encode())
    return h.hexdigest()


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read base face file {path}: {getattr(exc, 'strerror', None) or exc}") from None


def _parse_mesh(text: str, path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(468, 5) x, y, z, u, v rows and (m, 3) triangles from a face-geometry pbtxt."""
    try:
        vb = np.array(re.findall(r"vertex_buffer:\s*(\S+)", text), dtype=np.float64)
        ib = np.array(re.findall(r"index_buffer:\s*(\S+)", text), dtype=np.int64)
    except ValueError:
        raise InputError(f"base face mesh {path} has a non-numeric buffer entry") from None
    if vb.size != 5 * N_LANDMARKS or ib.size == 0 or ib.size % 3:
        raise InputError(f"base face mesh {path} is not a {N_LANDMARKS}-vertex triangle mesh")
    if ib.min() < 0 or ib.max() >= N_LANDMARKS:
        raise InputError(f"base face mesh {path} has a triangle index out of range")
    return vb.reshape(N_LANDMARKS, 5), ib.reshape(-1, 3).astype(np.int32)


def normalise(xyz: np.ndarray) -> np.ndarray:
    """(n, 3) -> (n, 3): scale to forehead-top-to-chin height 1 and centre the bounding box at 0."""
    scale = 1.0 / (xyz[TOP, 1] - xyz[CHIN, 1])
    centre = 0.5 * (xyz.min(axis=0) + xyz.max(axis=0))
    return (xyz - centre) * scale


def _loop_faces(faces: np.ndarray, loops: list[list[int]]) -> np.ndarray:
    """(m,) bool: triangles whose three corners all lie on one of the closed loops."""
    mask = np.zeros(len(faces), dtype=bool)
    for loop in loops:
        mask |= np.isin(faces, loop).all(axis=1)
    return mask


def load_base_face(path: str | Path | None = None) -> BaseFace:
    """Load the base face from a directory (or its mesh file); default: the one shipped in ``codec.data``."""
    p = DEFAULT_DIR if path is None else Path(path)
    folder = p.parent if p.is_file() else p
    if not folder.is_dir():
        raise InputError(f"base face directory {folder} does not exist")
    raw, faces = _parse_mesh(_read_text(folder / MESH_FILE), folder / MESH_FILE)
    try:
        meta = json.loads(_read_text(folder / FEATURES_FILE))
    except ValueError:
        raise InputError(f"base face file {folder / FEATURES_FILE} is malformed") from None
    vertices = normalise(raw[:, :3])
    return build_face(vertices, faces, np.column_stack([raw[:, 3], 1.0 - raw[:, 4]]), meta,
                      content_id(vertices, faces, meta), origin=str(folder / FEATURES_FILE))


def build_face(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, meta: dict, face_id: str,
               texture: np.ndarray | None = None, origin: str = "face model",
               motion: MotionBasis | None = None, picture: ReferencePicture | None = None) -> BaseFace:
    """A BaseFace from its parts, the masks derived from ``meta``'s loops; InputError naming
    ``origin`` if the feature points are not F1..F15 landmark indices."""
    try:
        points = {name: int(fp["landmark"]) for name, fp in meta["feature_points"].items()}
        lips = meta["loops"]["inner_lip_upper"] + meta["loops"]["inner_lip_lower"]
        eyes = [meta["loops"]["eye_left"], meta["loops"]["eye_right"]]
    except (ValueError, KeyError, TypeError, AttributeError):
        raise InputError(f"{origin}: malformed feature points") from None
    if len(points) != 15 or not all(0 <= i < N_LANDMARKS for i in points.values()):
        raise InputError(f"{origin}: needs F1..F15 landmark indices")
    vertices = np.asarray(vertices, dtype=np.float64)
    vertices.setflags(write=False)
    return BaseFace(
        vertices=vertices,
        faces=faces,
        uv=np.asarray(uv, dtype=np.float64),
        feature_points=points,
        mouth_faces=_loop_faces(faces, [sorted(set(lips))]),
        eye_faces=_loop_faces(faces, eyes),
        content_id=face_id,
        meta=meta,
        texture=texture,
        motion=motion,
        picture=picture,
    )
