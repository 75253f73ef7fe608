"""Numba shading of one fragment (Blinn-Phong in linear light) and the 2x2 resolve.

Per-triangle ``kind`` selects the material: SKIN (lit albedo or texture),
MOUTH (unlit cavity with a band of teeth under the upper lip, given per
column) or EYE + e (lit sclera with a dark iris and pupil around eye e's
centre). Specular uses per-frame half vectors (see codec.render) and a table
of specular * x ** shininess. The per-fragment helpers are inlined into
codec.raster.draw (inline="always"): called, they cost more than they compute.
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

FAST = {"nsz", "arcp", "contract", "afn", "reassoc"}  # no nnan/ninf: buffers hold inf


@njit(cache=True, fastmath=FAST, inline="always")
def sample(tex, u, v):
    """Bilinear, clamp-to-edge lookup of (h, w, 3) float32 tex at (u, v), v up: (r, g, b)."""
    h, w = tex.shape[0], tex.shape[1]
    fx = min(max(u * w - 0.5, 0.0), w - 1.0)
    fy = min(max((1.0 - v) * h - 0.5, 0.0), h - 1.0)
    ix, iy = np.uint64(fx), np.uint64(fy)  # unsigned: no negative-index wrapping
    jx, jy = min(ix + np.uint64(1), np.uint64(w - 1)), min(iy + np.uint64(1), np.uint64(h - 1))
    ax, ay = np.float32(fx - ix), np.float32(fy - iy)
    one = np.float32(1.0)
    w00, w01, w10, w11 = (one - ax) * (one - ay), ax * (one - ay), (one - ax) * ay, ax * ay
    return (w00 * tex[iy, ix, 0] + w01 * tex[iy, jx, 0] + w10 * tex[jy, ix, 0] + w11 * tex[jy, jx, 0],
            w00 * tex[iy, ix, 1] + w01 * tex[iy, jx, 1] + w10 * tex[jy, ix, 1] + w11 * tex[jy, jx, 1],
            w00 * tex[iy, ix, 2] + w01 * tex[iy, jx, 2] + w10 * tex[jy, ix, 2] + w11 * tex[jy, jx, 2])


@njit(cache=True, fastmath=FAST, inline="always")
def eye_albedo(eyes, e, x, y, z):
    """Sclera / iris / pupil albedo (r, g, b) of eye e at world point (x, y, z).

    eyes: (k, 7) float64 iris centre, unit eye axis and iris radius; the
    distance to the centre is measured across the axis.
    """
    dx, dy, dz = x - eyes[e, 0], y - eyes[e, 1], z - eyes[e, 2]
    along = dx * eyes[e, 3] + dy * eyes[e, 4] + dz * eyes[e, 5]
    d = math.sqrt(max(dx * dx + dy * dy + dz * dz - along * along, 0.0))
    radius = eyes[e, 6]
    iris = min(max((radius - d) / (EDGE * radius), 0.0), 1.0)
    pupil = min(max((PUPIL_RATIO * radius - d) / (EDGE * radius), 0.0), 1.0)
    return ((SCLERA[0] * (1.0 - iris) + IRIS[0] * iris) * (1.0 - pupil) + PUPIL[0] * pupil,
            (SCLERA[1] * (1.0 - iris) + IRIS[1] * iris) * (1.0 - pupil) + PUPIL[1] * pupil,
            (SCLERA[2] * (1.0 - iris) + IRIS[2] * iris) * (1.0 - pupil) + PUPIL[2] * pupil)


@njit(cache=True, fastmath=FAST, inline="always")
def mouth(teeth, x, y):
    """Linear RGB of the mouth at sample (x, y).

    teeth: (3, sW) float32 per sample column: the y of the upper lip, the
    teeth band's height and its brightness.
    """
    band = teeth[1, x] - (y + 0.5 - teeth[0, x])
    m = min(max(band, 0.0), 1.0) * teeth[2, x]
    return (MOUTH_DARK[0] + (TEETH[0] - MOUTH_DARK[0]) * m,
            MOUTH_DARK[1] + (TEETH[1] - MOUTH_DARK[1]) * m,
            MOUTH_DARK[2] + (TEETH[2] - MOUTH_DARK[2]) * m)


@njit(cache=True, fastmath=FAST, inline="always")
def lit(inv, dots, x, cr, cg, cb, ambient, light_rgb, spec_lut, spec_cut):
    """Linear RGB of albedo (cr, cg, cb) at x pixels along a run of one triangle's row.

    Along the run the unnormalised normal N is linear in x, so are its dot
    products with each light's direction L and half vector H: dots (k, 4)
    float64 holds N.L, dN.L/dx, N.H, dN.H/dx per light; inv is +-1/|N| at x
    (negative to light the side facing the viewer). ambient: float;
    light_rgb: (k, 3) float64 light colour times intensity; spec_lut
    (SPEC_STEPS + 2,) float64: specular * (i / SPEC_STEPS) ** shininess;
    spec_cut: n.h below which it is negligible.
    """
    r, g, b = ambient, ambient, ambient
    sr, sg, sb = 0.0, 0.0, 0.0
    for li in range(dots.shape[0]):
        ndl = (dots[li, 0] + dots[li, 1] * x) * inv
        if ndl <= 0.0:
            continue
        r += ndl * light_rgb[li, 0]
        g += ndl * light_rgb[li, 1]
        b += ndl * light_rgb[li, 2]
        ndh = (dots[li, 2] + dots[li, 3] * x) * inv
        if ndh > spec_cut:
            f = min(ndh, 1.0) * SPEC_STEPS
            i = int(f)
            spec = spec_lut[i] + (spec_lut[i + 1] - spec_lut[i]) * (f - i)
            sr += spec * light_rgb[li, 0]
            sg += spec * light_rgb[li, 1]
            sb += spec * light_rgb[li, 2]
    return cr * r + sr, cg * g + sg, cb * b + sb


@njit(cache=True, fastmath=FAST)
def resolve(nearness, linear, box, perspective, bg, decode, encode, image, depth):
    """Average each 2x2 block of samples inside box into one output pixel.

    nearness (sH, sW) float32 and linear (sH, sW, 3) float32 come from
    codec.raster.draw, box (x0, y0, x1, y1) in samples. bg: (H, W, 3) uint8
    sRGB stands in for uncovered samples; decode (256,) float64 sRGB->linear;
    encode (65536,) uint8 linear->sRGB. Writes image (H, W, 3) uint8 and
    depth (H, W) float32 (the nearest sample's) where any sample is covered;
    the caller fills the rest. Samples average in linear light.
    """
    for y in range(box[1] // 2, box[3] // 2 + 1):
        for x in range(box[0] // 2, box[2] // 2 + 1):
            covered = 0
            nearest = -np.inf
            ar, ag, ab = 0.0, 0.0, 0.0
            for sy in range(2 * y, 2 * y + 2):
                for sx in range(2 * x, 2 * x + 2):
                    near = nearness[sy, sx]
                    if near != -np.inf:
                        covered += 1
                        nearest = max(nearest, near)
                        ar += linear[sy, sx, 0]
                        ag += linear[sy, sx, 1]
                        ab += linear[sy, sx, 2]
            if covered == 0:
                continue
            empty = 4 - covered
            if empty:
                ar += empty * decode[bg[y, x, 0]]
                ag += empty * decode[bg[y, x, 1]]
                ab += empty * decode[bg[y, x, 2]]
            image[y, x, 0] = encode[int(min(max(ar * 0.25, 0.0), 1.0) * 65535.0 + 0.5)]
            image[y, x, 1] = encode[int(min(max(ag * 0.25, 0.0), 1.0) * 65535.0 + 0.5)]
            image[y, x, 2] = encode[int(min(max(ab * 0.25, 0.0), 1.0) * 65535.0 + 0.5)]
            depth[y, x] = 1.0 / nearest if perspective else -nearest
