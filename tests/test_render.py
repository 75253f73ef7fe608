"""Software renderer: exact coverage, occlusion, shading, texturing, anti-aliasing."""

import numpy as np
import pytest

from codec.camera import Camera
from codec.raster import MOUTH_DARK, rasterize
from codec.render import DirectionalLight, Material, Renderer, linear_to_srgb, srgb_to_linear

FLAT = Material(albedo=(1.0, 1.0, 1.0), ambient=1.0, specular=0.0)  # output = albedo/texture


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
    screen = pixel_camera(w, h).project(verts, (w, h))
    count = np.zeros((h, w), np.int32)
    rasterize(screen, faces, 0.01, 100.0, np.full((h, w), np.inf), np.full((h, w), -1, np.int32),
              np.zeros((h, w, 2)), count)
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
    screen = pixel_camera(64, 64).project(verts, (64, 64))
    zbuf, ids = np.full((64, 64), np.inf), np.full((64, 64), -1, np.int32)
    rasterize(screen, faces, 0.01, 100.0, zbuf, ids, np.zeros((64, 64, 2)), np.zeros((0, 0), np.int32))
    solo = np.full((64, 64), -1, np.int32)
    rasterize(screen, faces[near:near + 1], 0.01, 100.0, np.full((64, 64), np.inf), solo,
              np.zeros((64, 64, 2)), np.zeros((0, 0), np.int32))
    assert (ids == 1 - near).any()
    np.testing.assert_array_equal(ids[solo == 0], near)
    np.testing.assert_allclose(zbuf[solo == 0], 9.0)


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


def test_mouth_faces_render_dark_with_teeth_band():
    verts, faces, _ = quad(8, 8, 56, 56)
    renderer = Renderer(faces, size=(64, 64), mouth_faces=np.array([True, True]))
    image, _ = renderer.render(verts, pixel_camera(64, 64))
    dark = np.round(linear_to_srgb(np.array(MOUTH_DARK)) * 255)
    np.testing.assert_allclose(image[30:55, 10:54].reshape(-1, 3), np.broadcast_to(dark, (25 * 44, 3)), atol=1)
    assert image[9:14, 10:54].min() > 100  # teeth along the upper edge


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
                 lambda: Camera.perspective(60, eye=(0, 0, 1), target=(0, 0, 1)),
                 lambda: Camera.orthographic(-1, eye=(0, 0, 1), target=(0, 0, 0))):
        with pytest.raises(ValueError):
            call()
