"""Numba shading pass: per visible sample, Blinn-Phong in linear light, then sRGB.

Works on the output of codec.raster.rasterize, only inside the box it drew.
Per-triangle ``kind`` selects the material: SKIN (lit albedo or texture),
MOUTH (unlit cavity with a band of teeth under the upper lip, given per
column) or EYE + e (lit sclera with a dark iris and pupil around eye e's
centre). Costs are kept per pixel to one division and one square root plus
table lookups: specular uses per-frame half vectors (see Renderer) and a
table of specular * x ** shininess.
"""

import math

import numpy as np
from numba import njit

SKIN, MOUTH, EYE = 0, 1, 2
MOUTH_DARK = (0.03, 0.008, 0.008)  # linear RGB of the mouth cavity
TEETH = (0.55, 0.52, 0.45)  # linear RGB of lit teeth
SCLERA = (0.62, 0.58, 0.54)  # linear RGB albedos of the eye
IRIS = (0.09, 0.05, 0.03)
PUPIL = (0.01, 0.01, 0.01)
PUPIL_RATIO = 0.45  # pupil radius over iris radius
EDGE = 0.12  # width of the iris and pupil rims, in iris radii (soft edges)
SPEC_STEPS = 1024  # intervals of the specular table over n.h in [0, 1]

_FAST = {"nsz", "arcp", "contract", "afn", "reassoc"}  # no nnan/ninf: buffers hold inf


@njit(cache=True, fastmath=_FAST)
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


@njit(cache=True, fastmath=_FAST)
def _eye_albedo(d, radius):
    """Sclera / iris / pupil albedo at distance d from the eye centre: (r, g, b)."""
    iris = min(max((radius - d) / (EDGE * radius), 0.0), 1.0)
    pupil = min(max((PUPIL_RATIO * radius - d) / (EDGE * radius), 0.0), 1.0)
    return ((SCLERA[0] * (1.0 - iris) + IRIS[0] * iris) * (1.0 - pupil) + PUPIL[0] * pupil,
            (SCLERA[1] * (1.0 - iris) + IRIS[1] * iris) * (1.0 - pupil) + PUPIL[1] * pupil,
            (SCLERA[2] * (1.0 - iris) + IRIS[2] * iris) * (1.0 - pupil) + PUPIL[2] * pupil)


@njit(cache=True, fastmath=_FAST)
def shade(nearness, tri_id, plane, box, faces, inv_w, normals, pos, uv, tex, kind, albedo,
          ambient, light_dir, light_rgb, half_dir, spec_lut, spec_cut, view, teeth, eyes,
          perspective, bg, decode, encode, ss, image, depth):
    """Shade the samples inside box and resolve ss x ss of them into each output pixel.

    nearness (sH, sW) float32, tri_id (sH, sW) int32, plane (m, 6) float64
    and box (x0, y0, x1, y1) come from rasterize at ss times the output size.
    Per vertex: inv_w (n,) float64 (1/depth, or ones for orthographic),
    normals, pos (n, 3) float64, uv (n, 2) float64 (v up); tex (h, w, 3)
    float32 linear RGB, or shape (0, 0, 3) to use albedo (3,) float64.
    kind (m,) int8: SKIN, MOUTH or EYE + eye index. light_dir, light_rgb,
    half_dir: (k, 3) float64 unit direction to each light, its colour times
    intensity, and its unit half vector. spec_lut (SPEC_STEPS + 2,) float64:
    specular * (i / SPEC_STEPS) ** shininess; spec_cut: n.h below which it is
    negligible. view (4, 3): camera back, right and up axes, then (cx, cy,
    1/focal) in samples (1/focal = 0 for orthographic): the sign of n.v per
    sample makes lighting double-sided. teeth (3, sW) float32: per sample
    column the y of the upper lip, the teeth band's height and its
    brightness. eyes (e, 7) float64: iris centre, unit eye axis and iris
    radius (world); the distance to the centre is measured across the axis.
    bg: (H, W, 3) uint8 sRGB; decode (256,) float64 sRGB->linear; encode
    (65536,) uint8 linear->sRGB. Writes image (H, W, 3) uint8 and depth
    (H, W) float32 inside the box (the caller fills the rest): depth is the
    nearest sample's, +inf where none is covered. Samples average in linear
    light.
    """
    textured = tex.shape[0] > 0
    inv_count = 1.0 / (ss * ss)
    cx, cy, inv_f = view[3, 0], view[3, 1], view[3, 2]
    for y in range(box[1] // ss, box[3] // ss + 1):
        for x in range(box[0] // ss, box[2] // ss + 1):
            covered = 0
            nearest = -np.inf
            ar, ag, ab = 0.0, 0.0, 0.0
            for sy in range(y * ss, y * ss + ss):
                for sx in range(x * ss, x * ss + ss):
                    near = nearness[sy, sx]
                    if near == -np.inf:
                        continue
                    covered += 1
                    nearest = max(nearest, near)
                    t = tri_id[sy, sx]
                    a, b, c = faces[t, 0], faces[t, 1], faces[t, 2]
                    w1 = plane[t, 0] * sx + plane[t, 1] * sy + plane[t, 2]
                    w2 = plane[t, 3] * sx + plane[t, 4] * sy + plane[t, 5]
                    l0, l1, l2 = (1.0 - w1 - w2) * inv_w[a], w1 * inv_w[b], w2 * inv_w[c]
                    s = 1.0 / (l0 + l1 + l2)
                    q0, q1, q2 = l0 * s, l1 * s, l2 * s  # perspective-correct weights
                    k = kind[t]
                    if k == MOUTH:
                        band = teeth[1, sx] - (sy + 0.5 - teeth[0, sx])
                        m = min(max(band, 0.0), 1.0) * teeth[2, sx]
                        ar += MOUTH_DARK[0] + (TEETH[0] - MOUTH_DARK[0]) * m
                        ag += MOUTH_DARK[1] + (TEETH[1] - MOUTH_DARK[1]) * m
                        ab += MOUTH_DARK[2] + (TEETH[2] - MOUTH_DARK[2]) * m
                        continue
                    nx = q0 * normals[a, 0] + q1 * normals[b, 0] + q2 * normals[c, 0]
                    ny = q0 * normals[a, 1] + q1 * normals[b, 1] + q2 * normals[c, 1]
                    nz = q0 * normals[a, 2] + q1 * normals[b, 2] + q2 * normals[c, 2]
                    # unnormalised view vector of this sample's ray: only its sign matters
                    ox, oy = (sx + 0.5 - cx) * inv_f, (cy - sy - 0.5) * inv_f
                    facing = (nx * (view[0, 0] - ox * view[1, 0] - oy * view[2, 0])
                              + ny * (view[0, 1] - ox * view[1, 1] - oy * view[2, 1])
                              + nz * (view[0, 2] - ox * view[1, 2] - oy * view[2, 2]))
                    norm2 = nx * nx + ny * ny + nz * nz
                    inv = 1.0 / math.sqrt(norm2) if norm2 > 0.0 else 0.0
                    if facing < 0.0:
                        inv = -inv
                    nx, ny, nz = nx * inv, ny * inv, nz * inv
                    if k >= EYE:
                        e = k - EYE
                        dx = q0 * pos[a, 0] + q1 * pos[b, 0] + q2 * pos[c, 0] - eyes[e, 0]
                        dy = q0 * pos[a, 1] + q1 * pos[b, 1] + q2 * pos[c, 1] - eyes[e, 1]
                        dz = q0 * pos[a, 2] + q1 * pos[b, 2] + q2 * pos[c, 2] - eyes[e, 2]
                        along = dx * eyes[e, 3] + dy * eyes[e, 4] + dz * eyes[e, 5]
                        off2 = max(dx * dx + dy * dy + dz * dz - along * along, 0.0)
                        cr, cg, cb = _eye_albedo(math.sqrt(off2), eyes[e, 6])
                    elif textured:
                        cr, cg, cb = _sample(tex, q0 * uv[a, 0] + q1 * uv[b, 0] + q2 * uv[c, 0],
                                             q0 * uv[a, 1] + q1 * uv[b, 1] + q2 * uv[c, 1])
                    else:
                        cr, cg, cb = albedo[0], albedo[1], albedo[2]
                    r, g, bl = ambient, ambient, ambient
                    sr, sg, sb = 0.0, 0.0, 0.0
                    for li in range(light_dir.shape[0]):
                        ndl = nx * light_dir[li, 0] + ny * light_dir[li, 1] + nz * light_dir[li, 2]
                        if ndl <= 0.0:
                            continue
                        r += ndl * light_rgb[li, 0]
                        g += ndl * light_rgb[li, 1]
                        bl += ndl * light_rgb[li, 2]
                        ndh = nx * half_dir[li, 0] + ny * half_dir[li, 1] + nz * half_dir[li, 2]
                        if ndh > spec_cut:
                            f = min(ndh, 1.0) * SPEC_STEPS
                            i = int(f)
                            spec = spec_lut[i] + (spec_lut[i + 1] - spec_lut[i]) * (f - i)
                            sr += spec * light_rgb[li, 0]
                            sg += spec * light_rgb[li, 1]
                            sb += spec * light_rgb[li, 2]
                    ar += cr * r + sr
                    ag += cg * g + sg
                    ab += cb * bl + sb
            if covered == 0:
                continue  # the caller pre-filled background and +inf depth
            empty = ss * ss - covered
            if empty:
                ar += empty * decode[bg[y, x, 0]]
                ag += empty * decode[bg[y, x, 1]]
                ab += empty * decode[bg[y, x, 2]]
            image[y, x, 0] = encode[int(min(max(ar * inv_count, 0.0), 1.0) * 65535.0 + 0.5)]
            image[y, x, 1] = encode[int(min(max(ag * inv_count, 0.0), 1.0) * 65535.0 + 0.5)]
            image[y, x, 2] = encode[int(min(max(ab * inv_count, 0.0), 1.0) * 65535.0 + 0.5)]
            depth[y, x] = 1.0 / nearest if perspective else -nearest
