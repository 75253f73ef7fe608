"""Numba kernels of the software renderer: normals, rasterisation, shading.

Rasterisation is deferred: :func:`rasterize` only resolves visibility, storing
per pixel the nearest triangle and its perspective-correct barycentrics;
:func:`shade` then shades each visible pixel once, whatever the overdraw.

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

MOUTH_DARK = (0.03, 0.008, 0.008)  # linear RGB of the mouth cavity
TEETH = (0.55, 0.52, 0.45)  # linear RGB of the teeth band


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
def rasterize(screen, faces, near, far, zbuf, tri_id, bary, count):
    """Resolve visibility of all triangles, in index order.

    screen: (n, 4) float64 from Camera.project; faces: (m, 3) int32;
    zbuf: (H, W) float64, +inf initially; tri_id: (H, W) int32, -1 initially;
    bary: (H, W, 2) float64 receives the perspective-correct weights of
    faces[t, 1] and faces[t, 2]. A fragment replaces the stored one only if
    strictly nearer, so on equal depth the lower triangle index wins.
    count: (H, W) int32 counts every fragment (test aid), or shape (0, 0).
    """
    height, width = zbuf.shape
    counting = count.shape[0] > 0
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
        w0, w1, w2 = screen[i0, 3], screen[i1, 3], screen[i2, 3]
        area = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0)
        if area == 0:
            continue
        swapped = area < 0
        if swapped:  # one orientation for all: no culling, mixed winding is fine
            x1, y1, x2, y2 = x2, y2, x1, y1
            w1, w2 = w2, w1
            d1, d2 = d2, d1
            area = -area
        lo_x = max(0, int(math.ceil((min(x0, x1, x2) - SUBPIXEL // 2) / SUBPIXEL)))
        hi_x = min(width - 1, int(math.floor((max(x0, x1, x2) - SUBPIXEL // 2) / SUBPIXEL)))
        lo_y = max(0, int(math.ceil((min(y0, y1, y2) - SUBPIXEL // 2) / SUBPIXEL)))
        hi_y = min(height - 1, int(math.floor((max(y0, y1, y2) - SUBPIXEL // 2) / SUBPIXEL)))
        if lo_x > hi_x or lo_y > hi_y:
            continue
        # e_k(p) = (b - a) x (p - a) for the edge a->b opposite vertex k
        b0, b1, b2 = _bias(x1, y1, x2, y2), _bias(x2, y2, x0, y0), _bias(x0, y0, x1, y1)
        px = np.int64(lo_x) * SUBPIXEL + SUBPIXEL // 2
        inv_area = 1.0 / area
        s0, s1, s2 = (y2 - y1) * SUBPIXEL, (y0 - y2) * SUBPIXEL, (y1 - y0) * SUBPIXEL
        for py in range(lo_y, hi_y + 1):
            cy = np.int64(py) * SUBPIXEL + SUBPIXEL // 2
            e0 = (x2 - x1) * (cy - y1) - (y2 - y1) * (px - x1)
            e1 = (x0 - x2) * (cy - y2) - (y0 - y2) * (px - x2)
            e2 = (x1 - x0) * (cy - y0) - (y1 - y0) * (px - x0)
            for qx in range(lo_x, hi_x + 1):
                if ((e0 + b0) | (e1 + b1) | (e2 + b2)) >= 0:
                    l0 = e0 * inv_area * w0
                    l1 = e1 * inv_area * w1
                    l2 = e2 * inv_area * w2
                    s = 1.0 / (l0 + l1 + l2)
                    z = (l0 * d0 + l1 * d1 + l2 * d2) * s
                    if counting:
                        count[py, qx] += 1
                    if z < zbuf[py, qx]:
                        zbuf[py, qx] = z
                        tri_id[py, qx] = t
                        if swapped:
                            bary[py, qx, 0] = l2 * s
                            bary[py, qx, 1] = l1 * s
                        else:
                            bary[py, qx, 0] = l1 * s
                            bary[py, qx, 1] = l2 * s
                e0 -= s0
                e1 -= s1
                e2 -= s2


@njit(cache=True)
def _sample(tex, u, v):
    """Bilinear, clamp-to-edge lookup of (h, w, 3) float32 tex at (u, v), v up: (r, g, b)."""
    h, w = tex.shape[0], tex.shape[1]
    fx = min(max(u * w - 0.5, 0.0), w - 1.0)
    fy = min(max((1.0 - v) * h - 0.5, 0.0), h - 1.0)
    ix, iy = int(fx), int(fy)
    jx, jy = min(ix + 1, w - 1), min(iy + 1, h - 1)
    ax, ay = fx - ix, fy - iy
    w00, w01, w10, w11 = (1 - ax) * (1 - ay), ax * (1 - ay), (1 - ax) * ay, ax * ay
    return (w00 * tex[iy, ix, 0] + w01 * tex[iy, jx, 0] + w10 * tex[jy, ix, 0] + w11 * tex[jy, jx, 0],
            w00 * tex[iy, ix, 1] + w01 * tex[iy, jx, 1] + w10 * tex[jy, ix, 1] + w11 * tex[jy, jx, 1],
            w00 * tex[iy, ix, 2] + w01 * tex[iy, jx, 2] + w10 * tex[jy, ix, 2] + w11 * tex[jy, jx, 2])


# fast-math without the no-inf/no-NaN assumptions: depth uses +inf
_FAST = {"nsz", "arcp", "contract", "afn", "reassoc"}


@njit(cache=True, fastmath=_FAST)
def shade(tri_id, bary, zbuf, faces, normals, pos, uv, tex, mouth, upper, albedo,
          params, light_dir, light_rgb, eye, back, perspective, bg, decode, encode,
          ss, image, depth):
    """Shade visible samples and resolve ss x ss of them into each output pixel.

    tri_id (sH, sW) int32, bary (sH, sW, 2) float64, zbuf (sH, sW) float64
    come from :func:`rasterize` at ss times the output size. Per vertex:
    normals, pos (n, 3) float64, uv (n, 2) float64 (v up), upper (n,) float64
    (1 on the upper edge of the mouth, for the teeth band). tex (h, w, 3)
    float32 linear RGB, or shape (0, 0, 3) to use albedo (3,) float64.
    mouth: (m,) bool. params: (ambient, specular, shininess). light_dir,
    light_rgb: (k, 3) float64 unit directions toward the lights, colour times
    intensity. back: (3,) unit vector toward the viewer (orthographic case).
    bg: (H, W, 3) uint8 sRGB; decode: (256,) float64 sRGB->linear; encode:
    (65536,) uint8 linear->sRGB. Writes image (H, W, 3) uint8 and depth
    (H, W) float32: the nearest sample's depth, +inf where none is covered.
    Samples are averaged in linear light.
    """
    ambient, specular, shininess = params[0], params[1], params[2]
    textured = tex.shape[0] > 0
    inv_count = 1.0 / (ss * ss)
    # below this n.h the highlight adds under 1e-5 (a 1/65536 encoder step)
    spec_cut = (1e-5 / specular) ** (1.0 / shininess) if specular > 0.0 else 2.0
    for y in range(image.shape[0]):
        for x in range(image.shape[1]):
            covered = 0
            empty = 0
            nearest = np.inf
            ar, ag, ab = 0.0, 0.0, 0.0
            for sy in range(y * ss, y * ss + ss):
                for sx in range(x * ss, x * ss + ss):
                    t = tri_id[sy, sx]
                    if t < 0:
                        empty += 1
                        continue
                    covered += 1
                    nearest = min(nearest, zbuf[sy, sx])
                    q1, q2 = bary[sy, sx, 0], bary[sy, sx, 1]
                    q0 = 1.0 - q1 - q2
                    a, b, c3 = faces[t, 0], faces[t, 1], faces[t, 2]
                    if mouth[t]:
                        up = q0 * upper[a] + q1 * upper[b] + q2 * upper[c3]
                        k = min(max((up - 0.6) * 5.0, 0.0), 1.0)
                        ar += MOUTH_DARK[0] * (1.0 - k) + TEETH[0] * k
                        ag += MOUTH_DARK[1] * (1.0 - k) + TEETH[1] * k
                        ab += MOUTH_DARK[2] * (1.0 - k) + TEETH[2] * k
                        continue
                    nx = q0 * normals[a, 0] + q1 * normals[b, 0] + q2 * normals[c3, 0]
                    ny = q0 * normals[a, 1] + q1 * normals[b, 1] + q2 * normals[c3, 1]
                    nz = q0 * normals[a, 2] + q1 * normals[b, 2] + q2 * normals[c3, 2]
                    if perspective:
                        vx = eye[0] - (q0 * pos[a, 0] + q1 * pos[b, 0] + q2 * pos[c3, 0])
                        vy = eye[1] - (q0 * pos[a, 1] + q1 * pos[b, 1] + q2 * pos[c3, 1])
                        vz = eye[2] - (q0 * pos[a, 2] + q1 * pos[b, 2] + q2 * pos[c3, 2])
                        inv = 1.0 / math.sqrt(vx * vx + vy * vy + vz * vz)
                        vx, vy, vz = vx * inv, vy * inv, vz * inv
                    else:
                        vx, vy, vz = back[0], back[1], back[2]
                    norm = math.sqrt(nx * nx + ny * ny + nz * nz)
                    if norm == 0.0:
                        nx, ny, nz, norm = vx, vy, vz, 1.0
                    if nx * vx + ny * vy + nz * vz < 0.0:
                        norm = -norm  # double-sided: face the viewer
                    inv = 1.0 / norm
                    nx, ny, nz = nx * inv, ny * inv, nz * inv
                    if textured:
                        cr, cg, cb = _sample(tex, q0 * uv[a, 0] + q1 * uv[b, 0] + q2 * uv[c3, 0],
                                             q0 * uv[a, 1] + q1 * uv[b, 1] + q2 * uv[c3, 1])
                    else:
                        cr, cg, cb = albedo[0], albedo[1], albedo[2]
                    r, g, bl = ambient, ambient, ambient
                    sr, sg, sb = 0.0, 0.0, 0.0
                    for li in range(light_dir.shape[0]):
                        lx, ly, lz = light_dir[li, 0], light_dir[li, 1], light_dir[li, 2]
                        ndl = nx * lx + ny * ly + nz * lz
                        if ndl <= 0.0:
                            continue
                        r += ndl * light_rgb[li, 0]
                        g += ndl * light_rgb[li, 1]
                        bl += ndl * light_rgb[li, 2]
                        if specular > 0.0:
                            hx, hy, hz = lx + vx, ly + vy, lz + vz
                            hn = math.sqrt(hx * hx + hy * hy + hz * hz)
                            ndh = (nx * hx + ny * hy + nz * hz) / hn if hn > 0.0 else 0.0
                            if ndh > spec_cut:
                                spec = specular * ndh ** shininess
                                sr += spec * light_rgb[li, 0]
                                sg += spec * light_rgb[li, 1]
                                sb += spec * light_rgb[li, 2]
                    ar += cr * r + sr
                    ag += cg * g + sg
                    ab += cb * bl + sb
            if covered == 0:
                image[y, x, 0], image[y, x, 1], image[y, x, 2] = bg[y, x, 0], bg[y, x, 1], bg[y, x, 2]
                depth[y, x] = np.inf
                continue
            if empty:
                ar += empty * decode[bg[y, x, 0]]
                ag += empty * decode[bg[y, x, 1]]
                ab += empty * decode[bg[y, x, 2]]
            image[y, x, 0] = encode[int(min(max(ar * inv_count, 0.0), 1.0) * 65535.0 + 0.5)]
            image[y, x, 1] = encode[int(min(max(ag * inv_count, 0.0), 1.0) * 65535.0 + 0.5)]
            image[y, x, 2] = encode[int(min(max(ab * inv_count, 0.0), 1.0) * 65535.0 + 0.5)]
            depth[y, x] = nearest
