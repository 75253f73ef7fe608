"""Numba kernels of the software renderer: vertex normals and the triangle loop.

Rendering is forward: :func:`draw` walks each triangle's pixels and shades a
fragment as soon as it passes the depth test. A face mesh has almost no
overdraw (about 0.1% of fragments at 512x512), so this costs less than a
deferred pass that revisits every pixel of the drawn box.

Coverage is exact: vertices are snapped to 1/256 pixel and edge functions are
evaluated in int64, so the two triangles sharing an edge compute exactly
opposite values there, and the top-left rule (pixel centres at +0.5) gives
each pixel centre on a shared edge or vertex to exactly one triangle.
Triangles with a vertex nearer than the near plane or beyond the far plane
are skipped, not clipped (a talking face never crosses either plane), as
are triangles reaching more than GUARD pixels outside the image.

Attributes are interpolated as planes in screen space, set up once per
triangle: 1/w and every attribute times 1/w are linear in pixel position, and
dividing by the interpolated 1/w makes them perspective-correct. Normals skip
the division, since shading normalises them anyway.
"""

import math

import numpy as np
from numba import njit

from .shade import EYE, FAST, MOUTH, eye_albedo, lit, mouth, sample

SUBPIXEL = 256  # fixed-point steps per pixel
GUARD = float(1 << 18)  # keeps every int64 edge-function product below 2**55
# rows of the per-triangle attribute planes: 1/w, normal/w, uv/w, position/w, view ray
INV_W, NORMAL, UV, POS, RAY = 0, 1, 4, 6, 9


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
def _setup(planes, row, w1, w2, vals):
    """planes[row] = (d/dx, d/dy, value at pixel (0, 0)) of the attribute with vertex values vals."""
    d1, d2 = vals[1] - vals[0], vals[2] - vals[0]
    planes[row, 0] = d1 * w1[0] + d2 * w2[0]
    planes[row, 1] = d1 * w1[1] + d2 * w2[1]
    planes[row, 2] = vals[0] + d1 * w1[2] + d2 * w2[2]


@njit(cache=True, fastmath=FAST)
def draw(screen, key, perspective, normals, pos, uv, faces, kind, near, far, clear, nearness,
         count, shading, tex, teeth, eyes, encode, image, depth, linear):
    """Draw all triangles, in index order, into a cleared frame; return the drawn box.

    screen: (n, 4) float64 from Camera.project; key: (n,) float64 per-vertex
    nearness, linear in screen space and larger when nearer (1/depth for a
    perspective camera, -depth for an orthographic one, as perspective says); normals, pos: (n, 3)
    float64 unit normals and world positions; uv: (n, 2) float64 or (0, 2);
    faces: (m, 3) int32; kind: (m,) int8 material (codec.shade).
    clear: (x0, y0, x1, y1) inclusive box of nearness (sH, sW) float32 reset to
    -inf first (the previous frame's box; outside it must already be -inf).
    A fragment replaces the stored one only if strictly nearer, so on equal
    nearness the lower triangle index wins. count: (sH, sW) int32 counts
    every fragment (test aid), or shape (0, 0).
    shading: (ambient, albedo (3,), light_dir, light_rgb, half_dir, spec_lut,
    spec_cut, ray), the lighting of codec.shade.lit with albedo the untextured
    skin's linear RGB; ray (3, 3) rows: d/dx, d/dy and value at sample (0, 0)
    of a vector along the sample's view ray, whose sign against the normal
    tells the side seen. tex, teeth, eyes: see codec.shade.sample, mouth and
    eye_albedo. encode: (65536,) uint8 linear->sRGB. Fragments go to image
    (sH, sW, 3) uint8 and depth (sH, sW) float32 if linear has shape (0, 0,
    3), else to linear (sH, sW, 3) float32 as linear RGB, for
    codec.shade.resolve. The kernel is fastmath: the coverage and snapping
    arithmetic is integer or exact, so it is unaffected.
    Returns (x0, y0, x1, y1), inclusive, with x0 > x1 if nothing was drawn.
    """
    height, width = nearness.shape
    for y in range(clear[1], clear[3] + 1):
        nearness[y, clear[0]:clear[2] + 1] = -np.inf
    ambient, albedo, light_dir, light_rgb, half_dir, spec_lut, spec_cut, ray = shading
    box_x0, box_y0, box_x1, box_y1 = width, height, -1, -1
    counting = count.shape[0] > 0
    direct = linear.shape[0] == 0
    textured = tex.shape[0] > 0
    half = SUBPIXEL // 2
    planes = np.zeros((RAY + 3, 3))
    planes[RAY:] = ray.T
    rows = np.zeros(RAY + 3)
    dots = np.zeros((light_dir.shape[0], 4))
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
        v0, v1, v2 = i0, i1, i2
        area = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0)
        if area == 0:
            continue
        if area < 0:  # one orientation for all: no culling, mixed winding is fine
            x1, y1, x2, y2 = x2, y2, x1, y1
            v1, v2 = v2, v1
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
        c1 = (x0 - x2) * (half - y2) - (y0 - y2) * (half - x2)  # e1, e2 at pixel (0, 0)
        c2 = (x1 - x0) * (half - y0) - (y1 - y0) * (half - x0)
        w1 = (-s1 * inv_area, (x0 - x2) * SUBPIXEL * inv_area, c1 * inv_area)
        w2 = (-s2 * inv_area, (x1 - x0) * SUBPIXEL * inv_area, c2 * inv_area)
        k0, dk1, dk2 = key[v0], (key[v1] - key[v0]) * inv_area, (key[v2] - key[v0]) * inv_area
        k = kind[t]
        iw = (screen[v0, 3], screen[v1, 3], screen[v2, 3])
        _setup(planes, INV_W, w1, w2, iw)
        for j in range(3):
            _setup(planes, NORMAL + j, w1, w2, (normals[v0, j] * iw[0], normals[v1, j] * iw[1],
                                                normals[v2, j] * iw[2]))
            if k >= EYE:
                _setup(planes, POS + j, w1, w2, (pos[v0, j] * iw[0], pos[v1, j] * iw[1],
                                                 pos[v2, j] * iw[2]))
            elif textured and j < 2:
                _setup(planes, UV + j, w1, w2, (uv[v0, j] * iw[0], uv[v1, j] * iw[1],
                                                uv[v2, j] * iw[2]))
        px = np.int64(lo_x) * SUBPIXEL + half
        for py in range(lo_y, hi_y + 1):
            cy = np.int64(py) * SUBPIXEL + half
            e0 = (x2 - x1) * (cy - y1) - (y2 - y1) * (px - x1)
            e1 = (x0 - x2) * (cy - y2) - (y0 - y2) * (px - x2)
            e2 = (x1 - x0) * (cy - y0) - (y1 - y0) * (px - x0)
            qx = lo_x
            while qx <= hi_x and ((e0 + b0) | (e1 + b1) | (e2 + b2)) < 0:
                e0, e1, e2, qx = e0 - s0, e1 - s1, e2 - s2, qx + 1
            if qx > hi_x:
                continue
            # attributes at the run's first pixel; the normal N and ray V are linear
            # along it, so |N|^2, N.V and N.L, N.H per light are polynomials in x
            start = qx
            for r in range(RAY + 3):
                rows[r] = planes[r, 0] * start + planes[r, 1] * py + planes[r, 2]
            nx, ny, nz = rows[NORMAL], rows[NORMAL + 1], rows[NORMAL + 2]
            gx, gy, gz = planes[NORMAL, 0], planes[NORMAL + 1, 0], planes[NORMAL + 2, 0]
            norm_a, norm_b, norm_c = (nx * nx + ny * ny + nz * nz, 2.0 * (nx * gx + ny * gy + nz * gz),
                                      gx * gx + gy * gy + gz * gz)
            face_a = nx * rows[RAY] + ny * rows[RAY + 1] + nz * rows[RAY + 2]
            face_b = (nx * planes[RAY, 0] + ny * planes[RAY + 1, 0] + nz * planes[RAY + 2, 0]
                      + gx * rows[RAY] + gy * rows[RAY + 1] + gz * rows[RAY + 2])
            face_c = gx * planes[RAY, 0] + gy * planes[RAY + 1, 0] + gz * planes[RAY + 2, 0]
            for li in range(light_dir.shape[0]):
                dots[li, 0] = nx * light_dir[li, 0] + ny * light_dir[li, 1] + nz * light_dir[li, 2]
                dots[li, 1] = gx * light_dir[li, 0] + gy * light_dir[li, 1] + gz * light_dir[li, 2]
                dots[li, 2] = nx * half_dir[li, 0] + ny * half_dir[li, 1] + nz * half_dir[li, 2]
                dots[li, 3] = gx * half_dir[li, 0] + gy * half_dir[li, 1] + gz * half_dir[li, 2]
            while qx <= hi_x and ((e0 + b0) | (e1 + b1) | (e2 + b2)) >= 0:
                z = np.float32(k0 + e1 * dk1 + e2 * dk2)
                if counting:
                    count[py, qx] += 1
                if z > nearness[py, qx]:
                    nearness[py, qx] = z
                    x = np.float64(qx - start)
                    if k == MOUTH:
                        cr, cg, cb = mouth(teeth, qx, py)
                    else:
                        if k >= EYE:
                            s = 1.0 / (planes[INV_W, 0] * x + rows[INV_W])
                            ar, ag, ab = eye_albedo(eyes, k - EYE,
                                                    (planes[POS, 0] * x + rows[POS]) * s,
                                                    (planes[POS + 1, 0] * x + rows[POS + 1]) * s,
                                                    (planes[POS + 2, 0] * x + rows[POS + 2]) * s)
                        elif textured:
                            s = 1.0 / (planes[INV_W, 0] * x + rows[INV_W])
                            ar, ag, ab = sample(tex, (planes[UV, 0] * x + rows[UV]) * s,
                                                (planes[UV + 1, 0] * x + rows[UV + 1]) * s)
                        else:
                            ar, ag, ab = albedo[0], albedo[1], albedo[2]
                        norm2 = norm_a + x * (norm_b + x * norm_c)
                        inv = 1.0 / math.sqrt(norm2) if norm2 > 0.0 else 0.0
                        if face_a + x * (face_b + x * face_c) < 0.0:
                            inv = -inv
                        cr, cg, cb = lit(inv, dots, x, ar, ag, ab, ambient, light_rgb, spec_lut,
                                         spec_cut)
                    if direct:
                        image[py, qx, 0] = encode[int(min(max(cr, 0.0), 1.0) * 65535.0 + 0.5)]
                        image[py, qx, 1] = encode[int(min(max(cg, 0.0), 1.0) * 65535.0 + 0.5)]
                        image[py, qx, 2] = encode[int(min(max(cb, 0.0), 1.0) * 65535.0 + 0.5)]
                        depth[py, qx] = 1.0 / np.float64(z) if perspective else -z
                    else:
                        linear[py, qx, 0] = cr
                        linear[py, qx, 1] = cg
                        linear[py, qx, 2] = cb
                e0, e1, e2, qx = e0 - s0, e1 - s1, e2 - s2, qx + 1
    return box_x0, box_y0, box_x1, box_y1
