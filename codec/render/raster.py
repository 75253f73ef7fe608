"""Numba kernels of the software renderer: vertex normals, triangle loop with shading, 2x2 resolve.

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
the division, since shading normalises them anyway. Each row of a triangle is
one run of pixels, found from the edge functions by integer division; the
run's square roots and divisions go first, in loops of their own (which
vectorise), out of the long dependency chain of each fragment's shading.

A mesh drawn without lights and with its texture as it is (the whole picture)
skips normals and shading, and its textured pixels are left to an image warp:
draw writes each one's texel position into a map and marks it, and OpenCV's
remap samples the texture there, in its own sRGB encoding, for the marked
pixels (codec/render/render.py). A bilinear lookup is the fragment's whole cost, and
remap's SIMD code does it in a third of the time Numba's scalar code takes
(docs/hd.md).

Shading is Blinn-Phong in linear light. Per-triangle ``kind`` selects the
material: SKIN (lit albedo or texture), MOUTH (unlit cavity with a band of
teeth under the upper lip, given per column) or EYE + e (lit sclera with a
dark iris and pupil around eye e's centre). Specular uses one half vector per
light and frame and a table of specular * x ** shininess. The per-fragment
helpers are inlined into draw (inline="always"): called, they cost more than
they compute.

Everything compiled into draw (helpers and constants) must live in this file:
numba's disk cache of a function is invalidated only when the file defining
it changes, so a helper imported from another module could change without
draw being recompiled.
"""

import math
import sys

import numpy as np
from numba import njit

SUBPIXEL = 256  # fixed-point steps per pixel
GUARD = float(1 << 18)  # keeps every int64 edge-function product below 2**55
# rows of the per-triangle attribute planes: 1/w, normal/w, uv/w, position/w
INV_W, NORMAL, UV, POS = 0, 1, 4, 6
SKIN, MOUTH, EYE = 0, 1, 2
MOUTH_DARK = (0.03, 0.008, 0.008)  # linear RGB of the mouth cavity
TEETH = (0.55, 0.52, 0.45)  # linear RGB of lit teeth
SCLERA = (0.62, 0.58, 0.54)  # linear RGB albedos of the eye
IRIS = (0.09, 0.05, 0.03)
PUPIL = (0.01, 0.01, 0.01)
PUPIL_RATIO = 0.45  # pupil radius over iris radius
EDGE = 0.12  # width of the iris and pupil rims, in iris radii (soft edges)
SPEC_STEPS = 1024  # intervals of the specular table over n.h in [0, 1]
#: Where the int16 pair (x, y) of whole texels sits in the one int32 that draw stores for it.
X_SHIFT, Y_SHIFT = (0, 16) if sys.byteorder == "little" else (16, 0)
#: OpenCV's remap works in 1/32 texels (INTER_BITS 5): draw writes each texel position as its whole
#: texel and that fraction, rounded as remap rounds a float map, so remap skips the conversion.
REMAP_BITS = 5

# fast math touches only shading: coverage and snapping are integer or exact
# arithmetic; no nnan/ninf, since buffers hold inf
FAST = {"nsz", "arcp", "contract", "afn", "reassoc"}


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


@njit(cache=True, fastmath=FAST)
def _view(pos, perspective, axes, eye, inv_f, light_dir, width, height):
    """Per frame: (3, 3) view ray and (k, 3) unit half vectors of the (k, 3) unit light_dir.

    The ray rows are d/dx, d/dy and value at sample (0, 0) of a vector along
    the sample's view ray, whose sign against the normal tells the side
    seen. The half vectors use one view direction, from the mesh's centre
    to the eye (see codec.render.render). axes, eye, inv_f: see draw's view.
    """
    ray, toward, half = np.empty((3, 3)), np.empty(3), np.empty_like(light_dir)
    for j in range(3):
        ray[0, j] = -inv_f * axes[0, j]
        ray[1, j] = inv_f * axes[1, j]
        ray[2, j] = axes[2, j] + inv_f * ((0.5 * width - 0.5) * axes[0, j]
                                          - (0.5 * height - 0.5) * axes[1, j])
        toward[j] = eye[j] - pos[:, j].mean() if perspective else axes[2, j]
    norm = max(math.sqrt(toward[0] ** 2 + toward[1] ** 2 + toward[2] ** 2), 1e-300)
    for li in range(half.shape[0]):
        for j in range(3):
            half[li, j] = light_dir[li, j] + toward[j] / norm
        norm_h = max(math.sqrt(half[li, 0] ** 2 + half[li, 1] ** 2 + half[li, 2] ** 2), 1e-300)
        for j in range(3):
            half[li, j] /= norm_h
    return ray, half


@njit(cache=True)
def _bias(ax, ay, bx, by):
    """0 if edge a->b is a top or left edge (it owns its pixels), else -1."""
    dy = by - ay
    return 0 if dy < 0 or (dy == 0 and bx > ax) else -1


@njit(cache=True, inline="always")
def _clip(first, last, lo, f, s):
    """Narrow the run [first, last] to the x where f - s * (x - lo) >= 0 (one edge's test, exactly)."""
    if s > 0:
        return first, min(last, lo + f // s)
    if s < 0:
        return max(first, lo - f // -s), last
    return (first, last) if f >= 0 else (first, first - 1)


@njit(cache=True)
def _setup(planes, row, w1, w2, vals):
    """planes[row] = (d/dx, d/dy, value at pixel (0, 0)) of the attribute with vertex values vals."""
    d1, d2 = vals[1] - vals[0], vals[2] - vals[0]
    planes[row, 0] = d1 * w1[0] + d2 * w2[0]
    planes[row, 1] = d1 * w1[1] + d2 * w2[1]
    planes[row, 2] = vals[0] + d1 * w1[2] + d2 * w2[2]


@njit(cache=True, fastmath=FAST, inline="always")
def sample(tex, u, v):
    """Bilinear, clamp-to-edge lookup of (h, w, 3) float32 tex at (u, v), v up: (r, g, b)."""
    h, w = tex.shape[0], tex.shape[1]
    fx = min(max(u * w - 0.5, 0.0), w - 1.0)
    fy = min(max((1.0 - v) * h - 0.5, 0.0), h - 1.0)
    sx, sy = np.int64(fx), np.int64(fy)  # fx, fy >= 0: truncation is floor (signed: one instruction)
    ax, ay = np.float32(fx - sx), np.float32(fy - sy)
    ix, iy = np.uint64(sx), np.uint64(sy)  # unsigned indices: no negative-index wrapping
    jx, jy = min(ix + np.uint64(1), np.uint64(w - 1)), min(iy + np.uint64(1), np.uint64(h - 1))
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
    light_rgb: k (r, g, b) tuples of light colour times intensity (a tuple, so
    that k is known when compiling and the loop unrolls); spec_lut
    (SPEC_STEPS + 1, 2) float64: value and slope over interval i of specular
    * (i / SPEC_STEPS) ** shininess; spec_cut: n.h below which it is
    negligible.
    """
    r, g, b = ambient, ambient, ambient
    sr, sg, sb = 0.0, 0.0, 0.0
    for li in range(len(light_rgb)):
        ndl = (dots[li, 0] + dots[li, 1] * x) * inv
        if ndl <= 0.0:
            continue
        lr, lg, lb = light_rgb[li]
        r += ndl * lr
        g += ndl * lg
        b += ndl * lb
        ndh = (dots[li, 2] + dots[li, 3] * x) * inv
        if ndh > spec_cut:
            f = min(ndh, 1.0) * SPEC_STEPS
            i = np.uint64(f)
            spec = spec_lut[i, 0] + spec_lut[i, 1] * (f - i)
            sr += spec * lr
            sg += spec * lg
            sb += spec * lb
    return cr * r + sr, cg * g + sg, cb * b + sb


@njit(cache=True, fastmath=FAST, inline="always")
def _remap_run(run, first, uy, z0, dz, du, u0, dv, v0, w_a, dw, tw, th, nearness, count, counting,
               flat_near, flat_maps, flat_fractions, flat_warped, depth, keep_depth, perspective):
    """One row's run of a remapped triangle (see draw's maps) in one loop without branches, which
    vectorises: each pixel's texel position, the depth test, and stores that choose between the
    new value and the old one, into the buffers seen as flat rows (no view to make per run). A
    pixel's whole texels go out as one int32 laid out as the int16 pair (x, y) remap reads: two
    interleaved int16 stores kept the loop from vectorising (draw took 8.9 ms a 1080p frame with
    them, 5.2 without, frames identical). The nearness steps along the run in floating point
    (z0 - i dz) rather than from the integer edge functions: the same float32 on every pixel of
    the 1080p benchmark."""
    low = (1 << REMAP_BITS) - 1
    if counting or keep_depth:
        for i in range(run):
            ux = np.uint64(first + i)
            z = np.float32(z0 - dz * i)
            if counting:
                count[uy, ux] += 1
            if keep_depth and z > nearness[uy, ux]:
                depth[uy, ux] = 1.0 / np.float64(z) if perspective else -z
    at = uy * np.uint64(nearness.shape[1]) + np.uint64(first)
    for i in range(run):
        p = at + np.uint64(i)
        z = np.float32(z0 - dz * i)
        hit = z > flat_near[p]
        x = np.float64(i)
        w = 1.0 / (dw * x + w_a)
        tx = np.float32(min(max((du * x + u0) * w * tw - 0.5, 0.0), tw - 1.0))
        ty = np.float32(min(max((1.0 - (dv * x + v0) * w) * th - 0.5, 0.0), th - 1.0))
        fx = np.int32(np.rint(tx * np.float32(1 << REMAP_BITS)))
        fy = np.int32(np.rint(ty * np.float32(1 << REMAP_BITS)))
        flat_near[p] = z if hit else flat_near[p]
        flat_maps[p] = ((fy >> REMAP_BITS) << Y_SHIFT) | ((fx >> REMAP_BITS) << X_SHIFT) if hit else flat_maps[p]
        flat_fractions[p] = np.uint16(((fy & low) << REMAP_BITS) | (fx & low)) if hit else flat_fractions[p]
        flat_warped[p] = np.uint8(1) if hit else flat_warped[p]


@njit(cache=True, fastmath=FAST, error_model="numpy")
def draw(screen, perspective, pos, uv, faces, kind, near, far, clear, nearness, count, shading,
         view, tex, teeth, eyes, encode, image, depth, linear, maps, fractions, warped):
    """Draw all triangles, in index order, into a cleared frame; return the drawn box.

    screen: (n, 4) float64 from Camera.project (of a perspective camera if
    perspective); pos: (n, 3) float64 world positions; uv: (n, 2) float64 or
    (0, 2); faces: (m, 3) int32; kind: (m,) int8 material.
    clear: (x0, y0, x1, y1) inclusive box of nearness (sH, sW) float32 reset to
    -inf first (the previous frame's box; outside it must already be -inf).
    Nearness is 1/depth for a perspective camera, -depth for an orthographic
    one. A fragment replaces the stored one only if strictly nearer, so on
    equal nearness the lower triangle index wins. count: (sH, sW) int32
    counts every fragment (test aid), or shape (0, 0).
    shading: (ambient, albedo (3,), light_dir (k, 3) unit, light_rgb, spec_lut,
    spec_cut, flat), see lit, with albedo the untextured skin's linear RGB and flat
    True when there are no lights (ambient times albedo, no normals needed); view:
    (axes, eye, inv_f): Camera.basis(), Camera.eye and 1 / focal length in
    samples (0 if orthographic). tex, teeth, eyes: see sample,
    mouth and eye_albedo. encode: (65536,) uint8 linear->sRGB. Fragments go
    to image (sH, sW, 3) uint8 and depth (sH, sW) float32 if linear has shape
    (0, 0, 3), else to linear (sH, sW, 3) float32 as linear RGB, for resolve.
    maps: (sH, sW, 2) int16, fractions and warped (sH, sW) uint16 and uint8, or
    shapes (0, 0, 2) and (0, 0): if given, tex is uint8 sRGB drawn as it is, with its last
    column and row once more (a bilinear lookup's second taps there), and its
    fragments are not shaded here: each one's texel position (x, y down,
    centres at whole numbers, clamped to the texture) goes to maps (whole
    texels) and fractions (y and x in 1/32 texels, OpenCV's fixed-point map
    pair) for a remap, and warped marks them 1, every other drawn pixel 0 (the
    clear box first).
    depth of shape (0, 0): no depth is kept.
    Returns (x0, y0, x1, y1), inclusive, with x0 > x1 if nothing was drawn.
    error_model="numpy": no checks for division by zero, which would keep
    loops from vectorising.
    """
    height, width = nearness.shape
    deferred = maps.shape[0] > 0
    keep_depth = depth.shape[0] > 0
    for y in range(clear[1], clear[3] + 1):
        nearness[y, clear[0]:clear[2] + 1] = -np.inf
        if deferred:
            warped[y, clear[0]:clear[2] + 1] = 0
    ambient, albedo, light_dir, light_rgb, spec_lut, spec_cut, flat = shading
    ray, half_dir = _view(pos, perspective, *view, light_dir, width, height)
    normals = pos[:0] if flat else vertex_normals(pos, faces)
    box_x0, box_y0, box_x1, box_y1 = width, height, -1, -1
    counting = count.shape[0] > 0
    direct = linear.shape[0] == 0
    textured = tex.shape[0] > 0
    tw, th = np.float64(tex.shape[1] - deferred), np.float64(tex.shape[0] - deferred)  # without the repeats
    half = SUBPIXEL // 2
    planes = np.zeros((POS + 3, 3))
    dots = np.zeros((len(light_rgb), 4))
    attrs = np.zeros(3)  # uv/w or position/w at a run's first pixel
    scale = np.empty(width + 8)  # per pixel of a run: +-1/|N|
    w = np.empty(width)  # and w, for textures and eyes
    flat_near = nearness.reshape(-1)
    flat_maps = maps.reshape(-1).view(np.int32)  # a pixel's whole texels x, y as one store
    flat_fractions, flat_warped = fractions.reshape(-1), warped.reshape(-1)
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
        keys = (screen[v0, 3], screen[v1, 3], screen[v2, 3]) if perspective else \
            (-screen[v0, 2], -screen[v1, 2], -screen[v2, 2])
        k0, dk1, dk2 = keys[0], (keys[1] - keys[0]) * inv_area, (keys[2] - keys[0]) * inv_area
        k = kind[t]
        remapped = deferred and textured and k == SKIN  # left to the remap: see maps
        # the eye's position or the texture's uv need a perspective division per pixel
        attr, n_attr = (POS, 3) if k >= EYE else (UV, 2 if textured and k == SKIN else 0)
        vals = pos if k >= EYE else uv
        iw = (screen[v0, 3], screen[v1, 3], screen[v2, 3])
        _setup(planes, INV_W, w1, w2, iw)
        for j in range(0 if flat else 3):
            _setup(planes, NORMAL + j, w1, w2, (normals[v0, j] * iw[0], normals[v1, j] * iw[1],
                                                normals[v2, j] * iw[2]))
        for j in range(n_attr):
            _setup(planes, attr + j, w1, w2, (vals[v0, j] * iw[0], vals[v1, j] * iw[1],
                                              vals[v2, j] * iw[2]))
        # along a row the normal N and view ray V are linear in x, so |N|^2, N.V and
        # N.L, N.H per light are polynomials in x; their x-slopes are fixed per triangle
        gx, gy, gz = planes[NORMAL, 0], planes[NORMAL + 1, 0], planes[NORMAL + 2, 0]
        norm_c = gx * gx + gy * gy + gz * gz
        face_c = gx * ray[0, 0] + gy * ray[0, 1] + gz * ray[0, 2]
        for li in range(len(light_rgb)):
            dots[li, 1] = gx * light_dir[li, 0] + gy * light_dir[li, 1] + gz * light_dir[li, 2]
            dots[li, 3] = gx * half_dir[li, 0] + gy * half_dir[li, 1] + gz * half_dir[li, 2]
        for py in range(lo_y, hi_y + 1):
            cy = np.int64(py) * SUBPIXEL + half
            px = np.int64(lo_x) * SUBPIXEL + half
            e0 = (x2 - x1) * (cy - y1) - (y2 - y1) * (px - x1)
            e1 = (x0 - x2) * (cy - y2) - (y0 - y2) * (px - x2)
            e2 = (x1 - x0) * (cy - y0) - (y1 - y0) * (px - x0)
            first, last = _clip(lo_x, hi_x, lo_x, e0 + b0, s0)
            first, last = _clip(first, last, lo_x, e1 + b1, s1)
            first, last = _clip(first, last, lo_x, e2 + b2, s2)
            if first > last:
                continue
            run = last - first + 1
            if not flat:
                nx = planes[NORMAL, 0] * first + planes[NORMAL, 1] * py + planes[NORMAL, 2]
                ny = planes[NORMAL + 1, 0] * first + planes[NORMAL + 1, 1] * py + planes[NORMAL + 1, 2]
                nz = planes[NORMAL + 2, 0] * first + planes[NORMAL + 2, 1] * py + planes[NORMAL + 2, 2]
                vx = ray[0, 0] * first + ray[1, 0] * py + ray[2, 0]
                vy = ray[0, 1] * first + ray[1, 1] * py + ray[2, 1]
                vz = ray[0, 2] * first + ray[1, 2] * py + ray[2, 2]
                norm_a, norm_b = nx * nx + ny * ny + nz * nz, 2.0 * (nx * gx + ny * gy + nz * gz)
                face_a = nx * vx + ny * vy + nz * vz
                face_b = nx * ray[0, 0] + ny * ray[0, 1] + nz * ray[0, 2] + gx * vx + gy * vy + gz * vz
                for li in range(len(light_rgb)):
                    dots[li, 0] = nx * light_dir[li, 0] + ny * light_dir[li, 1] + nz * light_dir[li, 2]
                    dots[li, 2] = nx * half_dir[li, 0] + ny * half_dir[li, 1] + nz * half_dir[li, 2]
                for i in range((run + 7) // 8 * 8):  # whole vectors of 8: short runs vectorise too
                    norm2 = norm_a + i * (norm_b + i * norm_c)
                    inv = 1.0 / math.sqrt(norm2) if norm2 > 0.0 else 0.0
                    scale[i] = -inv if face_a + i * (face_b + i * face_c) < 0.0 else inv
            if n_attr:
                w_a = planes[INV_W, 0] * first + planes[INV_W, 1] * py + planes[INV_W, 2]
                if not remapped:
                    for i in range(run):
                        w[i] = 1.0 / (planes[INV_W, 0] * i + w_a)
                for j in range(n_attr):
                    attrs[j] = (planes[attr + j, 0] * first + planes[attr + j, 1] * py
                                + planes[attr + j, 2])
            uy = np.uint64(py)  # unsigned indices: no negative-index wrapping
            e1 -= s1 * (first - lo_x)
            e2 -= s2 * (first - lo_x)
            if remapped:
                _remap_run(run, first, uy, k0 + e1 * dk1 + e2 * dk2, s1 * dk1 + s2 * dk2,
                           planes[UV, 0], attrs[0], planes[UV + 1, 0], attrs[1], w_a, planes[INV_W, 0],
                           tw, th, nearness, count, counting, flat_near, flat_maps, flat_fractions,
                           flat_warped, depth, keep_depth, perspective)
                continue
            for i in range(run):
                qx = first + i
                ux = np.uint64(qx)
                z = np.float32(k0 + e1 * dk1 + e2 * dk2)
                e1, e2 = e1 - s1, e2 - s2
                if counting:
                    count[uy, ux] += 1
                if not z > nearness[uy, ux]:
                    continue
                nearness[uy, ux] = z
                if deferred:
                    warped[uy, ux] = 0
                if k == MOUTH:
                    cr, cg, cb = mouth(teeth, qx, py)
                else:
                    x = np.float64(i)
                    if k >= EYE:
                        ar, ag, ab = eye_albedo(eyes, k - EYE, (planes[POS, 0] * x + attrs[0]) * w[i],
                                                (planes[POS + 1, 0] * x + attrs[1]) * w[i],
                                                (planes[POS + 2, 0] * x + attrs[2]) * w[i])
                    elif textured:
                        ar, ag, ab = sample(tex, (planes[UV, 0] * x + attrs[0]) * w[i],
                                            (planes[UV + 1, 0] * x + attrs[1]) * w[i])
                    else:
                        ar, ag, ab = albedo[0], albedo[1], albedo[2]
                    if flat:
                        cr, cg, cb = ar * ambient, ag * ambient, ab * ambient
                    else:
                        cr, cg, cb = lit(scale[i], dots, x, ar, ag, ab, ambient, light_rgb, spec_lut,
                                         spec_cut)
                if direct:
                    image[uy, ux, 0] = encode[np.uint64(min(max(cr, 0.0), 1.0) * 65535.0 + 0.5)]
                    image[uy, ux, 1] = encode[np.uint64(min(max(cg, 0.0), 1.0) * 65535.0 + 0.5)]
                    image[uy, ux, 2] = encode[np.uint64(min(max(cb, 0.0), 1.0) * 65535.0 + 0.5)]
                    if keep_depth:
                        depth[uy, ux] = 1.0 / np.float64(z) if perspective else -z
                else:
                    linear[uy, ux, 0] = cr
                    linear[uy, ux, 1] = cg
                    linear[uy, ux, 2] = cb
    return box_x0, box_y0, box_x1, box_y1


@njit(cache=True, fastmath=FAST)
def resolve(nearness, linear, box, perspective, bg, decode, encode, image, depth):
    """Average each 2x2 block of samples inside box into one output pixel.

    nearness (sH, sW) float32 and linear (sH, sW, 3) float32 come from draw,
    box (x0, y0, x1, y1) in samples. bg: (H, W, 3) uint8 sRGB stands in for
    uncovered samples; decode (256,) float64 sRGB->linear; encode (65536,)
    uint8 linear->sRGB. Writes image (H, W, 3) uint8 and depth (H, W) float32
    (the nearest sample's; none if its shape is (0, 0)) where any sample is covered; the caller
    fills the rest. Samples average in linear light.
    """
    keep_depth = depth.shape[0] > 0
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
            if keep_depth:
                depth[y, x] = 1.0 / nearest if perspective else -nearest
