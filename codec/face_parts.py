"""Per-frame geometry of the mouth and eyes, which the shader draws with their own materials.

The mouth fill is drawn dark with the upper teeth showing as a band under the
upper lip; the eye fill as a sclera with an iris disc. Both are shaped per
pixel from a few numbers recomputed each frame from the deformed mesh, so
they follow the lips and lids without extra geometry.
"""

from __future__ import annotations

import numpy as np

TEETH_BAND = 0.09  # height of the visible upper teeth over the mouth's width
TEETH_SHARE = 0.4  # at most this share of the local opening (beyond LIPS_GAP) shows teeth
LIPS_GAP = 0.05  # a gap between the lips under this share of the mouth's width shows no teeth
IRIS_SCALE = 0.21  # iris radius over the eye's corner-to-corner width


def teeth_columns(screen: np.ndarray, mouth_vertices: np.ndarray, width: int) -> np.ndarray:
    """(3, width) float32 per pixel column: upper lip y, teeth band height, brightness.

    screen: (n, 4) projected vertices; mouth_vertices: indices of the mouth
    fill's vertices (the inner lip loop). The loop is split into upper and
    lower lip by the line through its leftmost and rightmost points (the
    corners); the band is TEETH_BAND of the mouth's width, at most
    TEETH_SHARE of the local opening less LIPS_GAP of the width (so parted
    lips read as a dark slit), and dims toward the corners.
    """
    out = np.zeros((3, width), np.float32)
    if len(mouth_vertices) < 3:
        return out
    xs, ys = screen[mouth_vertices, 0], screen[mouth_vertices, 1]
    left, right = np.argmin(xs), np.argmax(xs)
    span = xs[right] - xs[left]
    if not span > 0.0:
        return out
    line = ys[left] + (xs - xs[left]) * (ys[right] - ys[left]) / span
    cols = np.arange(width) + 0.5
    edges = []
    for side in (ys <= line, ys >= line):  # pixel y grows downward: upper lip first
        order = np.argsort(xs[side])
        edges.append(np.interp(cols, xs[side][order], ys[side][order]))
    top, bottom = edges
    out[0] = top
    out[1] = np.minimum(TEETH_BAND, TEETH_SHARE * np.maximum((bottom - top) / span - LIPS_GAP, 0.0)) * span
    u = (cols - 0.5 * (xs[left] + xs[right])) / (0.5 * span)
    out[2] = np.clip(1.0 - 0.6 * u * u, 0.0, 1.0)
    return out


def eye_components(faces: np.ndarray, eye_mask: np.ndarray) -> list[np.ndarray]:
    """Split the eye triangles into connected pieces (one per eye).

    faces: (m, 3) int; eye_mask: (m,) bool. Returns, per eye, the (k,) indices
    of its triangles, ordered by their lowest triangle index.
    """
    tris = np.flatnonzero(eye_mask)
    parent = {int(v): int(v) for v in np.unique(faces[tris])}

    def root(v: int) -> int:
        while parent[v] != v:
            parent[v] = parent[parent[v]]
            v = parent[v]
        return v

    for a, b, c in faces[tris].tolist():
        parent[root(b)] = root(a)
        parent[root(c)] = root(a)
    labels = np.array([root(int(faces[t, 0])) for t in tris], dtype=np.int64)
    return [tris[labels == label] for label in dict.fromkeys(labels.tolist())]


def eye_discs(vertices: np.ndarray, faces: np.ndarray, eyes: list[np.ndarray],
              irises: np.ndarray | None = None) -> np.ndarray:
    """(e, 7) float64 per eye: iris centre (3), unit eye axis (3), iris radius.

    The centre is the midpoint of the eye's two farthest vertices (its
    corners), which barely move when the lids do, or the nearest of the given
    (k, 3) ``irises`` (a gaze model's); the axis is the fill's area-weighted
    normal, along which the iris disc is projected.
    """
    out = np.zeros((max(len(eyes), 1), 7))
    for e, tris in enumerate(eyes):
        pts = vertices[np.unique(faces[tris])]
        dist2 = ((pts[:, None] - pts[None]) ** 2).sum(-1)
        i, j = np.unravel_index(np.argmax(dist2), dist2.shape)
        tri = vertices[faces[tris]]
        axis = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]).sum(0)
        norm = np.linalg.norm(axis)
        out[e, :3] = (pts[i] + pts[j]) / 2
        if irises is not None and len(irises):
            out[e, :3] = irises[np.argmin(((np.asarray(irises) - out[e, :3]) ** 2).sum(1))]
        out[e, 3:6] = axis / norm if norm > 0.0 else 0.0
        out[e, 6] = IRIS_SCALE * np.sqrt(dist2[i, j])
    return out
