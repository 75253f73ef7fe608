"""A face texture from a video frame: the frame warped into the base face's UV space.

Every triangle of the mesh is seen in the frame (its landmarks) and has a place
in the texture (its UVs); each texel takes the frame's colour at the same
barycentric position. With it the receiver can draw a person's own face.
"""

import cv2
import numpy as np

SEAM = 3  # texels grown around the UV islands, so bilinear lookups at their rims stay on the face


def uv_to_texel(uv: np.ndarray, size: int) -> np.ndarray:
    """(n, 2) UVs (v up) -> (n, 2) texel coordinates (x right, y down) of a size x size texture."""
    uv = np.asarray(uv, dtype=np.float64)
    return np.column_stack([uv[:, 0] * size, (1.0 - uv[:, 1]) * size])


def texture_from_frame(frame: np.ndarray, points: np.ndarray, uv: np.ndarray, faces: np.ndarray,
                       size: int = 512) -> np.ndarray:
    """(size, size, 3) uint8 texture, same channel order as ``frame``.

    frame: (H, W, 3) uint8; points: (n, 2) pixel positions of the mesh's
    vertices in the frame (landmark x, y); uv: (n, 2) texture coordinates;
    faces: (m, 3) triangles.
    """
    frame = np.ascontiguousarray(frame)
    points = np.asarray(points, dtype=np.float64)[:, :2]
    faces = np.asarray(faces, dtype=np.int64)
    if frame.ndim != 3 or frame.shape[2] != 3 or points.shape != (len(uv), 2):
        raise ValueError(f"need an (H, W, 3) frame and (n, 2) points for {len(uv)} vertices")
    texels = uv_to_texel(uv, size)
    owner = _triangle_ids(texels, faces, size)
    ys, xs = np.nonzero(owner >= 0)
    tri = faces[owner[ys, xs]]
    weights = _barycentric(np.column_stack([xs + 0.5, ys + 0.5]), texels[tri])
    source = np.einsum("ki,kij->kj", weights, points[tri])
    map_x = np.zeros((size, size), np.float32)
    map_y = np.zeros((size, size), np.float32)
    map_x[ys, xs], map_y[ys, xs] = source[:, 0] - 0.5, source[:, 1] - 0.5
    return cv2.remap(frame, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _triangle_ids(texels: np.ndarray, faces: np.ndarray, size: int) -> np.ndarray:
    """(size, size) int32: the triangle covering each texel, -1 outside; islands grown by SEAM."""
    owner = np.full((size, size), -1, np.int32)
    fixed = np.round(texels * 16).astype(np.int32)  # 4 fractional bits for fillConvexPoly
    for t, tri in enumerate(faces):
        cv2.fillConvexPoly(owner, fixed[tri], int(t), lineType=cv2.LINE_8, shift=4)
    ids = owner.astype(np.float32)  # exact for any mesh below 2**24 triangles; dilate wants floats
    for _ in range(SEAM):
        ids = np.where(ids >= 0, ids, cv2.dilate(ids, np.ones((3, 3), np.uint8)))
    return ids.astype(np.int32)


def _barycentric(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """(k, 3) barycentric weights of (k, 2) points in (k, 3, 2) triangles (outside: extrapolated)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    v0, v1, v2 = b - a, c - a, p - a
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    den = np.where(np.abs(den) < 1e-12, 1e-12, den)
    wb = (v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den
    wc = (v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den
    return np.column_stack([1.0 - wb - wc, wb, wc])
