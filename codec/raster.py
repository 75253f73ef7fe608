"""Numba kernels of the software renderer: vertex normals and rasterisation.

Rasterisation is deferred: :func:`rasterize` only resolves visibility, storing
per pixel the nearest triangle and its nearness; the shading pass
(codec.shade) recomputes barycentrics from per-triangle plane equations, so
the raster loop writes two numbers per fragment and shading runs once per
visible pixel, whatever the overdraw.

Coverage is exact: vertices are snapped to 1/256 pixel and edge functions are
evaluated in int64, so the two triangles sharing an edge compute exactly
opposite values there, and the top-left rule (pixel centres at +0.5) gives
each pixel centre on a shared edge or vertex to exactly one triangle.
Triangles with a vertex nearer than the near plane or beyond the far plane
are skipped, not clipped (a talking face never crosses either plane), as
are triangles reaching more than GUARD pixels outside the image.
"""

import math

import numpy as np
from numba import njit

SUBPIXEL = 256  # fixed-point steps per pixel
GUARD = float(1 << 18)  # keeps every int64 edge-function product below 2**55


@njit(cache=True)
def vertex_normals(vertices, faces):
    """(n, 3) float64 unit vertex normals: area-weighted sums of face normals.

    vertices: (n, 3) float64; faces: (m, 3) int32, counter-clockwise seen
    from the side the normal points to.
    """
    acc = np.zeros_like(vertices)
    for t in range(faces.shape[0]):
        a, b, c = faces[t, 0], faces[t, 1], faces[t, 2]
        ux = vertices[b, 0] - vertices[a, 0]
        uy = vertices[b, 1] - vertices[a, 1]
        uz = vertices[b, 2] - vertices[a, 2]
        vx = vertices[c, 0] - vertices[a, 0]
        vy = vertices[c, 1] - vertices[a, 1]
        vz = vertices[c, 2] - vertices[a, 2]
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        for k in (a, b, c):
            acc[k, 0] += nx
            acc[k, 1] += ny
            acc[k, 2] += nz
    for k in range(acc.shape[0]):
        norm = math.sqrt(acc[k, 0] ** 2 + acc[k, 1] ** 2 + acc[k, 2] ** 2)
        if norm > 0.0:
            acc[k] /= norm
    return acc


@njit(cache=True)
def _bias(ax, ay, bx, by):
    """0 if edge a->b is a top or left edge (it owns its pixels), else -1."""
    dy = by - ay
    return 0 if dy < 0 or (dy == 0 and bx > ax) else -1


@njit(cache=True)
def rasterize(screen, key, faces, near, far, clear, nearness, tri_id, plane, count):
    """Resolve visibility of all triangles, in index order; return the drawn box.

    screen: (n, 4) float64 from Camera.project; key: (n,) float64 per-vertex
    nearness, linear in screen space and larger when nearer (1/depth for a
    perspective camera, -depth for an orthographic one); faces: (m, 3) int32.
    clear: (x0, y0, x1, y1) inclusive box of nearness (H, W) float32 reset to
    -inf first (the previous frame's drawn box; pixels outside it must
    already be -inf). tri_id: (H, W) int32, valid where nearness > -inf.
    plane: (m, 6) float64 receives, per drawn triangle, the screen-linear
    weights of faces[t, 1] and faces[t, 2] as a*x + b*y + c of the pixel
    index (x, y). A fragment replaces the stored one only if strictly
    nearer, so on equal nearness the lower triangle index wins.
    count: (H, W) int32 counts every fragment (test aid), or shape (0, 0).
    Returns (x0, y0, x1, y1), inclusive, with x0 > x1 if nothing was drawn.
    """
    height, width = nearness.shape
    for y in range(clear[1], clear[3] + 1):
        nearness[y, clear[0]:clear[2] + 1] = -np.inf
    box_x0, box_y0, box_x1, box_y1 = width, height, -1, -1
    counting = count.shape[0] > 0
    half = SUBPIXEL // 2
    for t in range(faces.shape[0]):
        i0, i1, i2 = faces[t, 0], faces[t, 1], faces[t, 2]
        d0, d1, d2 = screen[i0, 2], screen[i1, 2], screen[i2, 2]
        if min(d0, d1, d2) < near or max(d0, d1, d2) > far:
            continue
        xs = (screen[i0, 0], screen[i1, 0], screen[i2, 0])
        ys = (screen[i0, 1], screen[i1, 1], screen[i2, 1])
        if not max(abs(xs[0] - 0.5 * width), abs(xs[1] - 0.5 * width), abs(xs[2] - 0.5 * width),
                   abs(ys[0] - 0.5 * height), abs(ys[1] - 0.5 * height),
                   abs(ys[2] - 0.5 * height)) <= GUARD:
            continue
        x0 = np.int64(math.floor(xs[0] * SUBPIXEL + 0.5))
        y0 = np.int64(math.floor(ys[0] * SUBPIXEL + 0.5))
        x1 = np.int64(math.floor(xs[1] * SUBPIXEL + 0.5))
        y1 = np.int64(math.floor(ys[1] * SUBPIXEL + 0.5))
        x2 = np.int64(math.floor(xs[2] * SUBPIXEL + 0.5))
        y2 = np.int64(math.floor(ys[2] * SUBPIXEL + 0.5))
        k0, k1, k2 = key[i0], key[i1], key[i2]
        area = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0)
        if area == 0:
            continue
        swapped = area < 0
        if swapped:  # one orientation for all: no culling, mixed winding is fine
            x1, y1, x2, y2 = x2, y2, x1, y1
            k1, k2 = k2, k1
            area = -area
        lo_x = max(0, (min(x0, x1, x2) - half + SUBPIXEL - 1) // SUBPIXEL)
        hi_x = min(width - 1, (max(x0, x1, x2) - half) // SUBPIXEL)
        lo_y = max(0, (min(y0, y1, y2) - half + SUBPIXEL - 1) // SUBPIXEL)
        hi_y = min(height - 1, (max(y0, y1, y2) - half) // SUBPIXEL)
        if lo_x > hi_x or lo_y > hi_y:
            continue
        box_x0, box_y0 = min(box_x0, lo_x), min(box_y0, lo_y)
        box_x1, box_y1 = max(box_x1, hi_x), max(box_y1, hi_y)
        # e_k(p) = (b - a) x (p - a) for the edge a->b opposite vertex k;
        # weight_k = e_k / area, and e_k steps by -s_k per pixel in x
        b0, b1, b2 = _bias(x1, y1, x2, y2), _bias(x2, y2, x0, y0), _bias(x0, y0, x1, y1)
        inv_area = 1.0 / area
        s0, s1, s2 = (y2 - y1) * SUBPIXEL, (y0 - y2) * SUBPIXEL, (y1 - y0) * SUBPIXEL
        r1, r2 = (x0 - x2) * SUBPIXEL, (x1 - x0) * SUBPIXEL  # steps of e1, e2 per row
        c1 = (x0 - x2) * (half - y2) - (y0 - y2) * (half - x2)  # e1, e2 at pixel (0, 0)
        c2 = (x1 - x0) * (half - y0) - (y1 - y0) * (half - x0)
        w1 = (-s1 * inv_area, r1 * inv_area, c1 * inv_area)
        w2 = (-s2 * inv_area, r2 * inv_area, c2 * inv_area)
        if swapped:
            w1, w2 = w2, w1
        plane[t, 0], plane[t, 1], plane[t, 2] = w1
        plane[t, 3], plane[t, 4], plane[t, 5] = w2
        dk1, dk2 = (k1 - k0) * inv_area, (k2 - k0) * inv_area
        px = np.int64(lo_x) * SUBPIXEL + half
        for py in range(lo_y, hi_y + 1):
            cy = np.int64(py) * SUBPIXEL + half
            e0 = (x2 - x1) * (cy - y1) - (y2 - y1) * (px - x1)
            e1 = (x0 - x2) * (cy - y2) - (y0 - y2) * (px - x2)
            e2 = (x1 - x0) * (cy - y0) - (y1 - y0) * (px - x0)
            for qx in range(lo_x, hi_x + 1):
                if ((e0 + b0) | (e1 + b1) | (e2 + b2)) >= 0:
                    z = np.float32(k0 + e1 * dk1 + e2 * dk2)
                    if counting:
                        count[py, qx] += 1
                    if z > nearness[py, qx]:
                        nearness[py, qx] = z
                        tri_id[py, qx] = t
                e0 -= s0
                e1 -= s1
                e2 -= s2
    return box_x0, box_y0, box_x1, box_y1
