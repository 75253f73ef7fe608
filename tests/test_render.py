"""Software renderer: exact coverage, occlusion, shading, texturing, anti-aliasing, mouth, eyes."""

import numpy as np
import pytest

from facedeform.codec.render import raster
from facedeform.codec.render.camera import Camera
from facedeform.codec.render.face_parts import (
    IRIS_SCALE,
    LIPS_GAP,
    TEETH_BAND,
    TEETH_SHARE,
    eye_components,
    eye_discs,
    eye_pieces,
    teeth_columns,
)
from facedeform.codec.render.raster import MOUTH_DARK, PUPIL, SCLERA
from facedeform.codec.render.render import DirectionalLight, Material, Renderer, linear_to_srgb, srgb_to_linear

FLAT = Material(albedo=(1.0, 1.0, 1.0), ambient=1.0, specular=0.0)  # output = albedo/texture


def fragments(verts, faces, w, h):
    """(h, w) int32 count of the fragments each pixel receives under pixel_camera."""
    count = np.zeros((h, w), np.int32)
    Renderer(faces, size=(w, h))._render(verts, pixel_camera(w, h), None, count)
    return count


def pixel_camera(w, h):
    """Orthographic camera mapping world (x, y, z) to pixel (x, h - y), looking down -z."""
    return Camera.orthographic(h, eye=(w / 2, h / 2, 10.0), target=(w / 2, h / 2, 0.0))


def grid_mesh(x0, x1, cells, jitter, rng):
    """Square [x0, x1]^2 (world = pixels) tiled by triangles, with a fan and a sliver."""
    t = np.linspace(x0, x1, cells + 1)
    xx, yy = np.meshgrid(t, t)
    inner = (xx > x0) & (xx < x1) & (yy > x0) & (yy < x1)
    step = (x1 - x0) / cells
    xx = xx + inner * rng.uniform(-jitter, jitter, xx.shape) * step
    yy = yy + inner * rng.uniform(-jitter, jitter, yy.shape) * step
    verts = [np.stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)], 1)]
    idx = lambda i, j: i * (cells + 1) + j  # noqa: E731
    faces = []
    for i in range(cells):
        for j in range(cells):
            a, b, c, d = idx(i, j), idx(i, j + 1), idx(i + 1, j + 1), idx(i + 1, j)
            if (i, j) == (1, 1):  # fan of four around the cell centre
                centre = sum(verts[0][k] for k in (a, b, c, d)) / 4
                verts.append(centre[None])
                e = len(np.concatenate(verts)) - 1
                faces += [(a, b, e), (b, c, e), (c, d, e), (d, a, e)]
            elif (i + j) % 2:
                faces += [(a, b, c), (a, d, c)]  # mixed winding on purpose
            else:
                faces += [(a, b, d), (b, c, d)]
    verts = np.concatenate(verts)
    for k in range(0, len(faces), 7):  # sub-pixel slivers: split an edge near its middle
        a, b, c = faces[k]
        s = (verts[a] + verts[b]) / 2 + (verts[c] - verts[a]) * 1e-3
        verts = np.vstack([verts, s])
        e = len(verts) - 1
        faces[k] = (a, e, c)
        faces += [(e, b, c), (a, b, e)]
    return verts, np.array(faces, np.int32)


@pytest.mark.parametrize("jitter", [0.0, 0.35])
def test_tiling_covers_every_pixel_exactly_once(jitter):
    w = h = 64
    verts, faces = grid_mesh(8.5, 56.5, 8, jitter, np.random.default_rng(1))
    count = fragments(verts, faces, w, h)
    # corners sit on pixel centres 8..56 (x) and 7..55 (y, flipped): the top-left
    # rule keeps the left and top edges and drops the right and bottom ones
    expected = np.zeros((h, w), np.int32)
    expected[7:55, 8:56] = 1
    np.testing.assert_array_equal(count, expected)


def test_renderer_leaves_no_holes_in_tiling():
    verts, faces = grid_mesh(8.5, 56.5, 8, 0.35, np.random.default_rng(2))
    _, depth = Renderer(faces, size=(64, 64)).render(verts, pixel_camera(64, 64))
    expected = np.zeros((64, 64), bool)
    expected[7:55, 8:56] = True
    np.testing.assert_array_equal(np.isfinite(depth), expected)


@pytest.mark.parametrize("order", [(0, 1), (1, 0)])
def test_nearer_triangle_wins_in_either_order(order):
    tris = [np.array([[4, 4, 1.0], [60, 10, 1.0], [20, 60, 1.0]]),   # nearer (z toward viewer)
            np.array([[10, 50, -2.0], [60, 60, -2.0], [40, 2, -2.0]])]
    verts = np.concatenate([tris[k] for k in order])
    faces = np.array([[0, 1, 2], [3, 4, 5]], np.int32)
    near = order.index(0)
    # a two-texel texture paints the nearer triangle red and the farther blue
    texture = np.uint8([[[255, 0, 0], [0, 0, 255]]])
    uv = np.where(np.arange(6)[:, None] // 3 == near, [0.25, 0.5], [0.75, 0.5])
    camera = pixel_camera(64, 64)
    image, depth = Renderer(faces, size=(64, 64), material=FLAT, lights=(), uv=uv,
                            texture=texture).render(verts, camera)
    _, solo = Renderer(faces[near:near + 1], size=(64, 64)).render(verts, camera)
    covered = np.isfinite(solo)
    assert (image == (0, 0, 255)).all(-1).any()
    np.testing.assert_array_equal(image[covered], np.broadcast_to([255, 0, 0], (covered.sum(), 3)))
    np.testing.assert_allclose(depth[covered], 9.0)


def test_flat_triangle_matches_lambert():
    angle = np.radians(50)
    light = DirectionalLight((np.sin(angle), 0.0, np.cos(angle)), intensity=0.8)
    mat = Material(albedo=(0.6, 0.4, 0.2), ambient=0.1, specular=0.0)
    verts = np.array([[2, 2, 0], [62, 2, 0], [32, 62, 0.0]])
    image, depth = Renderer([[0, 1, 2]], size=(64, 64), material=mat, lights=(light,)).render(
        verts, pixel_camera(64, 64))
    expected = np.round(linear_to_srgb(np.array(mat.albedo) * (0.1 + 0.8 * np.cos(angle))) * 255)
    np.testing.assert_allclose(image[40, 32], expected, atol=1)
    np.testing.assert_allclose(depth[40, 32], 10.0)
    assert np.isinf(depth[0, 0])


def uv_sphere(radius, rings=32, segments=64):
    th, ph = np.meshgrid(np.linspace(0, np.pi, rings + 1), np.linspace(0, 2 * np.pi, segments + 1))
    verts = radius * np.stack([np.sin(th) * np.cos(ph), np.cos(th), np.sin(th) * np.sin(ph)], -1)
    n = rings + 1
    faces = [(i * n + j, i * n + j + 1, (i + 1) * n + j + 1) for i in range(segments) for j in range(rings)]
    faces += [(i * n + j, (i + 1) * n + j + 1, (i + 1) * n + j) for i in range(segments) for j in range(rings)]
    return verts.reshape(-1, 3), np.array(faces, np.int32)


def test_sphere_specular_highlight_position():
    verts, faces = uv_sphere(1.0)
    light = np.array([0.5, 0.6, 0.62])
    mat = Material(albedo=(0.0, 0.0, 0.0), ambient=0.0, specular=0.8, shininess=60.0)
    camera = Camera.orthographic(2.5, eye=(0, 0, 5), target=(0, 0, 0))
    image, _ = Renderer(faces, size=(128, 128), material=mat,
                        lights=(DirectionalLight(tuple(light)),)).render(verts, camera)
    half = light / np.linalg.norm(light) + (0, 0, 1)
    peak = camera.project((half / np.linalg.norm(half))[None], (128, 128))[0, :2]
    y, x = np.unravel_index(np.argmax(image.sum(-1)), image.shape[:2])
    np.testing.assert_allclose([x + 0.5, y + 0.5], peak, atol=1.5)


def quad(x0, y0, x1, y1, z=0.0):
    verts = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], float)
    return verts, np.array([[0, 1, 2], [0, 2, 3]], np.int32), np.array([[0, 0], [1, 0], [1, 1], [0, 1.0]])


def test_checkerboard_texture_at_cell_centres():
    cells = np.indices((8, 8)).sum(0) % 2 == 1
    colours = np.where(cells[..., None], np.uint8([200, 40, 30]), np.uint8([20, 90, 220]))
    colours[0, 0] = (250, 250, 0)  # marks the top-left cell: catches flips
    texture = np.repeat(np.repeat(colours, 4, 0), 4, 1)
    verts, faces, uv = quad(8, 8, 56, 56)  # world y up = image rows down from 56
    image, _ = Renderer(faces, size=(64, 64), material=FLAT, lights=(), uv=uv,
                        texture=texture).render(verts, pixel_camera(64, 64))
    centres = 8 + 6 * np.arange(8) + 3
    np.testing.assert_allclose(image[np.ix_(centres, centres)], colours, atol=1)


def test_unlit_texture_is_sampled_in_its_own_encoding():
    """With no lights the texture is drawn as it is stored (sRGB, fixed point, no conversions):
    within a level of the lit path's linear-light lookup on a smooth texture; a patch shows."""
    ramp = np.linspace(20, 230, 24)
    texture = np.stack(np.broadcast_arrays(ramp[None, :], ramp[:, None], ramp[::-1][None, :]), -1).astype(np.uint8)
    verts, faces, uv = quad(4, 4, 60, 60)
    own = Renderer(faces, size=(64, 64), material=FLAT, lights=(), uv=uv, texture=texture)
    dark = DirectionalLight((0.0, 0.0, 1.0), intensity=0.0)  # lit path, adds nothing
    lit = Renderer(faces, size=(64, 64), material=FLAT, lights=(dark,), uv=uv, texture=texture)
    a, b = (r.render(verts, pixel_camera(64, 64))[0] for r in (own, lit))
    assert np.abs(a.astype(int) - b).max() <= 1 and np.abs(a.astype(int) - b).mean() < 0.3
    own.patch_texture(0, 0, np.zeros((12, 12, 3), np.uint8))  # the texture's top left quarter
    patched = own.render(verts, pixel_camera(64, 64))[0]
    assert patched[10:28, 10:28].max() == 0 and np.array_equal(patched[40:58, 40:58], a[40:58, 40:58])


def test_texture_interpolation_is_perspective_correct():
    verts = np.array([[-1, -1, -2], [1, -1, -2], [1, 1, -6], [-1, 1, -6.0]])
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1.0]])
    texture = np.zeros((64, 4, 3), np.uint8)
    texture[:32] = 255  # upper half (v > 0.5) white
    camera = Camera.perspective(60.0, eye=(0, 0, 0), target=(0, 0, -1))
    image, _ = Renderer([[0, 1, 2], [0, 2, 3]], size=(128, 128), material=FLAT, lights=(),
                        uv=uv, texture=texture).render(verts, camera)
    column = srgb_to_linear(image[:, 64, 0] / 255.0)
    rows = np.flatnonzero((column[:-1] > 0.5) & (column[1:] <= 0.5))  # white above, black below
    assert len(rows) == 1
    # v = 0.5 is the 3-D midpoint (0, 0, -4), which projects to the image centre;
    # affine screen-space interpolation would put it f/6 ~ 18 px lower
    np.testing.assert_allclose(rows[0] + 1.0, 64.0, atol=1.0)


def lens(cx, cy, half_width, half_height):
    """Eye- or mouth-shaped flat polygon at z = 0: (8, 3) vertices, (6, 3) triangles."""
    xs = cx + half_width * np.array([-1, -0.5, 0, 0.5, 1, 0.5, 0, -0.5])
    ys = cy + half_height * np.array([0, 0.9, 1, 0.9, 0, -0.9, -1, -0.9])
    faces = [(0, 1, 7), (1, 2, 7), (2, 6, 7), (2, 3, 6), (3, 5, 6), (3, 4, 5)]
    return np.stack([xs, ys, np.zeros(8)], 1), np.array(faces, np.int32)


def test_open_mouth_is_dark_with_thin_teeth_band():
    verts, faces = lens(32, 32, 24, 14)  # pixel rows 18..46, columns 8..56
    image, _ = Renderer(faces, size=(64, 64), mouth_faces=np.ones(6, bool)).render(
        verts, pixel_camera(64, 64))
    dark = np.round(linear_to_srgb(np.array(MOUTH_DARK)) * 255)
    np.testing.assert_allclose(image[24:45, 24:41].reshape(-1, 3), np.broadcast_to(dark, (21 * 17, 3)),
                               atol=1)
    assert image[18:21, 30:35].min() > 100  # teeth under the upper lip, ~4 px = 0.09 mouth widths


def test_nearly_closed_mouth_shows_no_teeth():
    verts, faces = lens(32, 32, 24, 0.75)  # a 1.5 px gap between the lips
    image, _ = Renderer(faces, size=(64, 64), mouth_faces=np.ones(6, bool)).render(
        verts, pixel_camera(64, 64))
    assert image[30:34, 20:44].max() < 60


def test_faces_set_between_frames_change_what_and_how_they_draw():
    verts, faces = lens(32, 32, 24, 14)
    uv = verts[:, :2] / 64.0
    texture = np.full((8, 8, 3), 200, np.uint8)
    source = faces.copy()
    renderer = Renderer(source, size=(64, 64), material=FLAT, lights=(), uv=uv, texture=texture,
                        mouth_faces=np.ones(6, bool))
    camera = pixel_camera(64, 64)
    assert renderer.render(verts, camera)[0][32, 32].max() < 60  # the cavity
    renderer.set_faces([2, 3], faces[[2, 3]], [False, False])  # the middle two drawn as skin, the texture
    image = renderer.render(verts, camera)[0]
    assert image[32, 32].min() == 200 and image[32, 12].max() < 60
    renderer.set_faces([2, 3], faces[[3, 2]], [True, True])  # and back
    assert renderer.render(verts, camera)[0][32, 32].max() < 60
    np.testing.assert_array_equal(source, faces)  # the renderer's faces are its own
    eyes = Renderer(faces, size=(64, 64), eye_faces=np.ones(6, bool))
    for index, new, mouth in (([0], [[0, 1, 99]], [True]), ([6], faces[:1], [True]), ([0], faces[:1], [True, False])):
        with pytest.raises(ValueError):
            renderer.set_faces(index, new, mouth)
    with pytest.raises(ValueError, match="eye"):
        eyes.set_faces([0], faces[:1], [False])


def test_eyes_have_dark_centres_and_light_corners():
    left, faces = lens(18, 32, 12, 6)
    right, _ = lens(46, 32, 12, 6)
    verts = np.vstack([left, right])
    faces = np.vstack([faces, faces + 8])
    renderer = Renderer(faces, size=(64, 64), material=FLAT, lights=(), eye_faces=np.ones(12, bool))
    image, _ = renderer.render(verts, pixel_camera(64, 64))
    sclera = np.round(linear_to_srgb(np.array(SCLERA)) * 255)
    pupil = np.round(linear_to_srgb(np.array(PUPIL)) * 255)
    for cx in (18, 46):  # pixel centre (cx, 32) is each eye's centre
        np.testing.assert_allclose(image[32, cx - 1:cx + 1], [pupil, pupil], atol=1)
        np.testing.assert_allclose(image[31:33, cx - 10], [sclera, sclera], atol=1)
        np.testing.assert_allclose(image[31:33, cx + 9], [sclera, sclera], atol=1)
        assert image[32, cx - 4:cx + 4].sum(-1).max() < image[32, cx - 10].sum()


def test_reused_renderer_matches_fresh_one():
    big, faces, _ = quad(2, 2, 62, 62)
    small, _, _ = quad(20, 24, 40, 36, z=1.0)
    camera = pixel_camera(64, 64)
    renderer = Renderer(faces, size=(64, 64), supersample=2, background=(10, 20, 30))
    renderer.render(big, camera)
    again = renderer.render(small, camera)
    fresh = Renderer(faces, size=(64, 64), supersample=2, background=(10, 20, 30)).render(small, camera)
    for got, want in zip(again, fresh):
        np.testing.assert_array_equal(got, want)


@pytest.mark.slow
def test_face_renders_eyes_mouth_and_depth():
    from facedeform.codec.model.face_model import load_base_face

    face = load_base_face()
    camera = Camera.perspective(20.0, eye=(0, 0, 4.4), target=(0, 0, 0))
    image, depth = Renderer(face.faces, size=(128, 128), mouth_faces=face.mouth_faces,
                            eye_faces=face.eye_faces).render(face.vertices, camera)
    covered = np.isfinite(depth)
    assert 0.2 < covered.mean() < 0.6
    assert 4.4 - 0.6 < depth[covered].min() and depth[covered].max() < 4.4 + 0.6
    screen = camera.project(face.vertices, (128, 128))
    for eye in ((face.faces[face.eye_faces] < 240).all(1), (face.faces[face.eye_faces] >= 240).all(1)):
        (x0, y0), (x1, y1) = screen[np.unique(face.faces[face.eye_faces][eye]), :2].min(0).astype(int), \
            screen[np.unique(face.faces[face.eye_faces][eye]), :2].max(0).astype(int)
        patch = image[y0:y1 + 1, x0:x1 + 1].sum(-1)
        assert patch.min() < 120 and patch.max() > 450  # a dark pupil in a light sclera


def test_supersampling_matches_inside_and_blends_edges():
    verts = np.array([[3.0, 5, 0], [61, 20, 0], [20, 61, 0]])
    camera = pixel_camera(64, 64)
    images = [Renderer([[0, 1, 2]], size=(64, 64), material=FLAT, lights=(), supersample=s)
              .render(verts, camera)[0][..., 0] for s in (1, 2)]
    solid = images[0] == 255
    interior = solid & np.roll(solid, 1, 0) & np.roll(solid, -1, 0) & np.roll(solid, 1, 1) & np.roll(solid, -1, 1)
    np.testing.assert_array_equal(images[1][interior], 255)
    np.testing.assert_array_equal(images[1][(images[0] == 0) & ~np.roll(solid, 1, 0)
                                            & ~np.roll(solid, -1, 0) & ~np.roll(solid, 1, 1)
                                            & ~np.roll(solid, -1, 1)], 0)
    coverage = srgb_to_linear(images[1] / 255.0) * 4
    np.testing.assert_allclose(coverage, np.round(coverage), atol=0.02)  # k/4 of the samples
    assert set(np.unique(np.round(coverage))) == {0, 1, 2, 3, 4}
    area = 0.5 * np.linalg.norm(np.cross(verts[1] - verts[0], verts[2] - verts[0]))
    np.testing.assert_allclose(coverage.sum() / 4, area, rtol=0.02)


def test_bad_input_raises_value_error():
    verts, faces, uv = quad(8, 8, 56, 56)
    camera = pixel_camera(64, 64)
    renderer = Renderer(faces, size=(64, 64))
    bad_verts = verts.copy()
    bad_verts[2, 1] = np.nan
    for call in (lambda: renderer.render(bad_verts, camera),
                 lambda: renderer.render(verts[:3], camera),
                 lambda: renderer.render(verts[:, :2], camera),
                 lambda: renderer.render(verts, "camera"),
                 lambda: Renderer(faces[:, :2]),
                 lambda: Renderer(faces.astype(float)),
                 lambda: Renderer(faces, supersample=3),
                 lambda: Renderer(faces, uv=uv),
                 lambda: Renderer(faces, uv=uv, texture=np.zeros((4, 4, 3))),
                 lambda: Renderer(faces, size=(64, 64), background=np.zeros((32, 32, 3), np.uint8)),
                 lambda: Renderer(faces, mouth_faces=[True]),
                 lambda: Renderer(faces, eye_faces=np.ones(3, bool)),
                 lambda: Renderer(faces, mouth_faces=np.ones(2, bool), eye_faces=np.ones(2, bool)),
                 lambda: Camera.perspective(60, eye=(0, 0, 1), target=(0, 0, 1)),
                 lambda: Camera.orthographic(-1, eye=(0, 0, 1), target=(0, 0, 0))):
        with pytest.raises(ValueError):
            call()


def reference_eye_discs(vertices, faces, eyes, irises):
    """eye_discs written plainly in numpy: farthest-pair centre, summed face normal, radius."""
    out = np.zeros((len(eyes), 7))
    for e, tris in enumerate(eyes):
        pts = vertices[np.unique(faces[tris])]
        dist2 = ((pts[:, None] - pts[None]) ** 2).sum(-1)
        i, j = np.unravel_index(np.argmax(dist2), dist2.shape)
        tri = vertices[faces[tris]]
        axis = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]).sum(0)
        out[e, :3] = (pts[i] + pts[j]) / 2
        if len(irises):
            out[e, :3] = irises[np.argmin(((irises - out[e, :3]) ** 2).sum(1))]
        out[e, 3:6] = axis / np.linalg.norm(axis)
        out[e, 6] = IRIS_SCALE * np.sqrt(dist2[i, j])
    return out


@pytest.mark.parametrize("irises", [np.zeros((0, 3)), np.array([[0.3, 0.2, 0.1], [-0.3, 0.2, 0.1]])])
def test_eye_discs_match_reference(irises):
    from facedeform.codec.model.face_model import load_base_face

    face = load_base_face()
    faces = face.faces.astype(np.int32)
    verts = face.vertices + np.random.default_rng(4).normal(0, 0.003, face.vertices.shape)
    eyes = eye_components(faces, face.eye_faces)
    got = eye_discs(verts, faces, *eye_pieces(faces, eyes), irises)
    np.testing.assert_allclose(got, reference_eye_discs(verts, faces, eyes, irises), atol=1e-12)


def reference_teeth_columns(screen, mouth_vertices, width):
    """teeth_columns written plainly in numpy: lips split by the corner line, interpolated per column."""
    out = np.zeros((3, width), np.float32)
    xs, ys = screen[mouth_vertices, 0], screen[mouth_vertices, 1]
    left, right = np.argmin(xs), np.argmax(xs)
    span = xs[right] - xs[left]
    line = ys[left] + (xs - xs[left]) * (ys[right] - ys[left]) / span
    cols = np.arange(width) + 0.5
    top, bottom = (np.interp(cols, np.sort(xs[side]), ys[side][np.argsort(xs[side])])
                   for side in (ys <= line, ys >= line))
    out[0] = top
    out[1] = np.minimum(TEETH_BAND, TEETH_SHARE * np.maximum((bottom - top) / span - LIPS_GAP, 0.0)) * span
    out[2] = np.clip(1.0 - 0.6 * ((cols - 0.5 * (xs[left] + xs[right])) / (0.5 * span)) ** 2, 0.0, 1.0)
    return out


@pytest.mark.parametrize("opening", [0.0, 8.0])
def test_teeth_columns_match_reference(opening):
    from facedeform.codec.model.deform import Deformer
    from facedeform.codec.model.face_model import load_base_face

    face = load_base_face()
    params = np.zeros(13)
    params[0] = opening  # the jaw's angle
    verts = Deformer(face).deform(params)
    screen = Camera.perspective(20.0, eye=(0, 0, 4.4), target=(0, 0, 0)).project(verts, (512, 512))
    mouth = np.unique(face.faces[face.mouth_faces])
    np.testing.assert_array_equal(teeth_columns(screen, mouth, 512),
                                  reference_teeth_columns(screen, mouth, 512))


def test_raster_compiles_nothing_from_other_modules():
    """numba's disk cache of draw is invalidated only when raster.py changes: all it inlines lives there."""
    import inspect

    source = inspect.getsource(raster)
    assert "from ." not in source and "facedeform" not in source


def test_camera_basis_is_a_copy_of_fixed_axes():
    camera = Camera.perspective(30.0, eye=(1, 2, 5), target=(0, 0, 0))
    axes = camera.basis()
    np.testing.assert_allclose(axes @ axes.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(axes[2], np.array([1, 2, 5]) / np.sqrt(30))
    axes[:] = 0.0
    assert np.abs(camera.basis()).sum() > 0  # callers cannot disturb the camera


@pytest.mark.parametrize("supersample", [1, 2])
@pytest.mark.parametrize("lit", [False, True])
def test_the_image_alone_is_the_rendered_image(supersample, lit):
    """Renderer.image keeps no depth buffer and draws the same pixels as render."""
    ramp = np.linspace(20, 230, 24)
    texture = np.stack(np.broadcast_arrays(ramp[None, :], ramp[:, None], ramp[::-1][None, :]), -1).astype(np.uint8)
    verts, faces, uv = quad(4, 4, 60, 60)
    lights = (DirectionalLight((0.3, 0.2, 1.0)),) if lit else ()
    renderer = Renderer(faces, size=(64, 64), material=FLAT, lights=lights, uv=uv, texture=texture,
                        supersample=supersample)
    image, depth = renderer.render(verts, pixel_camera(64, 64))
    np.testing.assert_array_equal(renderer.image(verts, pixel_camera(64, 64)), image)
    assert np.isfinite(depth).any()  # render still keeps its depth
