"""Per-frame geometry of the mouth and eyes, which the shader draws with their own materials.

The mouth fill is drawn dark with the upper teeth showing as a band under the
upper lip; the eye fill as a sclera with an iris disc. Both are shaped per
pixel from a few numbers recomputed each frame from the deformed mesh, so
they follow the lips and lids without extra geometry.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

TEETH_BAND = 0.09  # height of the visible upper teeth over the mouth's width
TEETH_SHARE = 0.4  # at most this share of the local opening (beyond LIPS_GAP) shows teeth
LIPS_GAP = 0.05  # a gap between the lips under this share of the mouth's width shows no teeth
IRIS_SCALE = 0.21  # iris radius over the eye's corner-to-corner width


@njit(cache=True)
def teeth_columns(screen, mouth_vertices, width):
    """(3, width) float32 per pixel column: upper lip y, teeth band height, brightness.

    screen: (n, 4) float64 projected vertices; mouth_vertices: (k,) int
    indices of the mouth fill's vertices (the inner lip loop). The loop is
    split into upper and lower lip by the line through its leftmost and
    rightmost points (the corners); the band is TEETH_BAND of the mouth's
    width, at most TEETH_SHARE of the local opening less LIPS_GAP of the
    width (so parted lips read as a dark slit), and dims toward the corners.
    Each lip is interpolated per column as np.interp does; plain loops, as
    numba compiles them in a fraction of the time np.interp and np.argsort take.
    """
    out = np.zeros((3, width), np.float32)
    n = len(mouth_vertices)
    if n < 3:
        return out
    xs, ys = np.empty(n), np.empty(n)
    for i in range(n):
        xs[i], ys[i] = screen[mouth_vertices[i], 0], screen[mouth_vertices[i], 1]
    left, right = np.argmin(xs), np.argmax(xs)
    span = xs[right] - xs[left]
    if not span > 0.0:
        return out
    order = np.arange(n)  # by x: an insertion sort, the loop is short
    for i in range(1, n):
        j = i
        while j > 0 and xs[order[j - 1]] > xs[order[j]]:
            order[j - 1], order[j] = order[j], order[j - 1]
            j -= 1
    edges = np.empty((2, width))
    lip_x, lip_y = np.empty(n), np.empty(n)
    for side in range(2):  # pixel y grows downward: upper lip first
        m = 0
        for i in order:
            line = ys[left] + (xs[i] - xs[left]) * (ys[right] - ys[left]) / span
            on_side = ys[i] <= line if side == 0 else ys[i] >= line
            if on_side:
                lip_x[m], lip_y[m] = xs[i], ys[i]
                m += 1
        j = 0  # lip points at or left of the column's centre
        for c in range(width):
            x = c + 0.5
            while j < m and lip_x[j] <= x:
                j += 1
            if j == 0 or j == m or lip_x[j - 1] == x:
                edges[side, c] = lip_y[max(j - 1, 0)]
            else:
                slope = (lip_y[j] - lip_y[j - 1]) / (lip_x[j] - lip_x[j - 1])
                edges[side, c] = slope * (x - lip_x[j - 1]) + lip_y[j - 1]
    for c in range(width):
        top, bottom = edges[0, c], edges[1, c]
        u = (c + 0.5 - 0.5 * (xs[left] + xs[right])) / (0.5 * span)
        out[0, c] = top
        out[1, c] = min(TEETH_BAND, TEETH_SHARE * max((bottom - top) / span - LIPS_GAP, 0.0)) * span
        out[2, c] = min(max(1.0 - 0.6 * u * u, 0.0), 1.0)
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


def eye_pieces(faces: np.ndarray, eyes: list[np.ndarray]) -> tuple[np.ndarray, ...]:
    """Flatten eye_components' list for eye_discs: (tri_start, tris, vertex_start, vertices).

    Eye e owns triangles tris[tri_start[e]:tri_start[e + 1]] and vertices
    vertices[vertex_start[e]:vertex_start[e + 1]]; all int64.
    """
    verts = [np.unique(faces[tris]) for tris in eyes]
    starts = [np.cumsum([0] + [len(p) for p in parts]) for parts in (eyes, verts)]
    flat = [np.concatenate(parts).astype(np.int64) if parts else np.zeros(0, np.int64)
            for parts in (eyes, verts)]
    return starts[0], flat[0], starts[1], flat[1]


@njit(cache=True)
def eye_discs(vertices, faces, tri_start, tris, vertex_start, eye_vertices, irises):
    """(max(e, 1), 7) float64 per eye: iris centre (3), unit eye axis (3), iris radius.

    vertices: (n, 3) float64; faces: (m, 3) int32; the eyes as eye_pieces
    lays them out. The centre is the midpoint of the eye's two farthest
    vertices (its corners), which barely move when the lids do, or the
    nearest of the (k, 3) float64 irises (a gaze model's; k may be 0); the
    axis is the fill's area-weighted normal, along which the iris disc is
    projected.
    """
    out = np.zeros((max(len(tri_start) - 1, 1), 7))
    for e in range(len(tri_start) - 1):
        best, bi, bj = -1.0, 0, 0
        for i in range(vertex_start[e], vertex_start[e + 1]):
            for j in range(vertex_start[e], vertex_start[e + 1]):
                a, b = eye_vertices[i], eye_vertices[j]
                d2 = ((vertices[a, 0] - vertices[b, 0]) ** 2 + (vertices[a, 1] - vertices[b, 1]) ** 2
                      + (vertices[a, 2] - vertices[b, 2]) ** 2)
                if d2 > best:
                    best, bi, bj = d2, a, b
        ax, ay, az = 0.0, 0.0, 0.0
        for k in range(tri_start[e], tri_start[e + 1]):
            p, q, r = faces[tris[k], 0], faces[tris[k], 1], faces[tris[k], 2]
            ux, uy, uz = vertices[q, 0] - vertices[p, 0], vertices[q, 1] - vertices[p, 1], \
                vertices[q, 2] - vertices[p, 2]
            vx, vy, vz = vertices[r, 0] - vertices[p, 0], vertices[r, 1] - vertices[p, 1], \
                vertices[r, 2] - vertices[p, 2]
            ax += uy * vz - uz * vy
            ay += uz * vx - ux * vz
            az += ux * vy - uy * vx
        for c in range(3):
            out[e, c] = (vertices[bi, c] + vertices[bj, c]) / 2
        if irises.shape[0] > 0:
            nearest, pick = np.inf, 0
            for k in range(irises.shape[0]):
                d2 = ((irises[k, 0] - out[e, 0]) ** 2 + (irises[k, 1] - out[e, 1]) ** 2
                      + (irises[k, 2] - out[e, 2]) ** 2)
                if d2 < nearest:
                    nearest, pick = d2, k
            out[e, :3] = irises[pick]
        norm = math.sqrt(ax * ax + ay * ay + az * az)
        if norm > 0.0:
            out[e, 3], out[e, 4], out[e, 5] = ax / norm, ay / norm, az / norm
        out[e, 6] = IRIS_SCALE * math.sqrt(best)
    return out
