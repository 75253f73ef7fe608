"""The whole picture: placement maths, the scene mesh, the views, and a synthetic scene through
enrol, send and receive."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from facedeform.codec.face_file.format import Face, decode_face, encode_face, save_face_file
from facedeform.codec.model.deform import Deformer
from facedeform.codec.model.face_model import ReferencePicture, load_base_face, mouth_vertices
from facedeform.codec.model.head_pose import head_pivot
from facedeform.codec.render.camera import Camera
from facedeform.codec.render.picture import (
    MOUTH_GAP,
    RINGS,
    BodyRegion,
    Placement,
    SceneMesh,
    body_shift,
    frame_placement,
    global_matrix,
    global_motion,
    outer_loop,
    relative_pose,
    warp_map,
)
from facedeform.codec.render.render import Renderer
from facedeform.common.errors import InputError
from facedeform.common.parameters import BODY_PARAMS, EXTENDED_PARAMS, GLOBAL_PARAMS, slots
from facedeform.protocol.stream import Header, steps_for
from facedeform.receiver.face_view import FaceView, PictureView, default_look, open_view
from facedeform.sender.motion_global import GlobalMotion, RingWeights, face_mask
from facedeform.sender.texture import texture_from_frame
from facedeform.sender.tracker import FaceTracker
from tests.support import ROOT

GRID = ROOT / "samples" / "grid_bbaf2n.mpg"
BASE = load_base_face()
NAMES = ("theta", "rx", "ry", "rz", "tx", "ty", "tz")


def rotation(rng) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def test_relative_pose_and_frame_placement_are_inverse():
    rng = np.random.default_rng(1)
    pivot = head_pivot(BASE.vertices)
    for _ in range(20):
        ref = Placement(rng.uniform(50, 200), rotation(rng), rng.uniform(-100, 100, 3))
        turn = cv2.Rodrigues(rng.uniform(-0.3, 0.3, 3))[0]
        frame = Placement(ref.scale * rng.uniform(0.8, 1.25), turn @ ref.rotation, rng.uniform(-100, 100, 3))
        back = frame_placement(ref, relative_pose(ref, frame, pivot), pivot)
        # the image is the same; only the depth of the whole head is not sent
        np.testing.assert_allclose(back.apply(BASE.vertices)[:, :2], frame.apply(BASE.vertices)[:, :2], atol=1e-6)
    np.testing.assert_allclose(relative_pose(ref, ref, pivot), np.zeros(6), atol=1e-9)


def test_the_projection_matrix_round_trips_and_only_similarities_are_accepted():
    rng = np.random.default_rng(2)
    place = Placement(80.0, rotation(rng), np.array([120.0, -90.0, 4.0]))
    back = Placement.from_matrix(place.matrix())
    np.testing.assert_allclose(back.apply(BASE.vertices), place.apply(BASE.vertices), atol=1e-9)
    # pixel y runs down: a point above the face centre has a smaller row
    top, chin = place.matrix() @ np.append(BASE.vertices[10], 1), place.matrix() @ np.append(BASE.vertices[152], 1)
    assert (top[1] < chin[1]) == (place.rotation[1, 1] > 0)
    mirrored = np.eye(3, 4)  # y down as the pixels are, but z still toward the viewer: a mirror image
    for bad in (np.full((3, 4), np.nan), place.matrix() * [[1], [2], [1]], mirrored, np.zeros((3, 4))):
        with pytest.raises(ValueError):
            Placement.from_matrix(bad)


def test_the_rings_go_around_the_face_and_the_outermost_stays_put():
    loop = outer_loop(BASE.faces)
    assert len(loop) == 36 and len(set(loop.tolist())) == 36
    place = Placement(100.0, np.eye(3), np.array([128.0, -128.0, 0.0]))
    scene = SceneMesh(BASE, ReferencePicture(np.zeros((256, 256, 3), np.uint8), place.matrix()))
    n, rings = len(BASE.vertices), len(RINGS)
    assert len(scene.uv) == n + rings * len(loop)
    moved = frame_placement(place, np.array([0, 0, 0, 0.2, 0.1, 0.0]), scene.pivot)
    pos = scene.positions(BASE.vertices, moved)
    rest = scene.positions(BASE.vertices, place)
    shift = np.linalg.norm(pos[:, :2] - rest[:, :2], axis=1)
    np.testing.assert_allclose(shift[:n], 100 * np.hypot(0.2, 0.1), rtol=1e-9)  # the face moves whole
    per_ring = shift[n:].reshape(rings, -1)
    assert np.all(np.diff(per_ring.mean(axis=1)) < 0)  # less and less outward
    np.testing.assert_allclose(per_ring[-1], 0.0, atol=1e-9)


def a_face_with_a_picture(size=(200, 160), scale=60.0):
    """The generic face placed in a textured picture (no tracking needed)."""
    w, h = size
    y, x = np.mgrid[0:h, 0:w]
    image = np.dstack([(x * 255 // w), (y * 255 // h), 128 + 100 * np.sin(x / 7.0) * np.cos(y / 9.0)]).astype(np.uint8)
    place = Placement(scale, np.eye(3), np.array([w / 2, -h / 2, 0.0]))
    return replace(BASE, picture=ReferencePicture(image, place.matrix()))


def header(face, names=NAMES, size=(0, 0)):
    return Header(25.0, names, steps_for(names), face.content_id, width=size[0], height=size[1])


def test_rest_parameters_draw_the_reference_picture_and_an_open_mouth_its_cavity():
    face = a_face_with_a_picture()
    view = PictureView(header(face), face, (200, 160))
    # exactly: the generic face's parted lips, a sliver at this size, are drawn from the picture where they
    # lie (they were a dashed dark line, which the tracker reads as parted lips)
    np.testing.assert_array_equal(view.render(np.zeros(len(NAMES))), face.picture.image)
    large = a_face_with_a_picture((400, 320), scale=140.0)  # the same lips over two pixels apart: the cavity
    for theta in (0.0, 20.0):
        drawn = PictureView(header(large, ("theta",)), large, (400, 320)).render(np.array([theta]))
        cavity = (drawn.max(axis=2) < 60) & (large.picture.image.max(axis=2) > 60)
        rows = np.flatnonzero(cavity.any(axis=1))
        assert cavity.sum() > 50 and np.all(np.abs(rows - 160 - 0.2 * 140) < 10)


def test_the_head_moves_in_the_picture_and_the_background_stays_exactly():
    face = a_face_with_a_picture()
    view = PictureView(header(face), face, (200, 160))
    still = view.render(np.zeros(len(NAMES)))
    moved = view.render(np.array([0, 0, 0, 0, 0.15, 0, 0]))  # a tenth of the face height... and a half
    changed = np.any(moved != still, axis=2)
    cols = np.flatnonzero(changed.any(axis=0))
    assert changed[:, 100].any() and cols.min() > 5 and cols.max() < 194  # the middle moves, the sides do not
    np.testing.assert_array_equal(moved[:, :5], face.picture.image[:, :5])


def test_the_layer_video_frame_is_carried_with_the_face_and_the_camera():
    face = a_face_with_a_picture()
    names = NAMES + GLOBAL_PARAMS
    view = PictureView(header(face, names), face, (200, 160))
    first = view.model_picture(np.zeros(len(names)), 0)
    video = cv2.resize(first, (100, 80), interpolation=cv2.INTER_AREA)  # the layer's small frame of frame 0
    assert view.carry(video, 0) is video  # at its own frame: the video itself

    def error(a, b):
        return np.abs(a.astype(int) - b).mean()

    for params in ([0, 0, 8, 0, 0.1, 0, 0, 0, 0, 0, 0],  # the head turns and moves
                   [0, 0, 0, 0, 0, 0, 0, 0.1, 0.05, 0.05, 2.0]):  # the camera moves
        moved = cv2.resize(view.model_picture(np.array(params, dtype=float), 1), (100, 80),
                           interpolation=cv2.INTER_AREA)
        carried = view.carry(video, 0)
        assert carried.shape == video.shape and error(carried, moved) < 0.5 * error(video, moved)


def test_size_scales_the_picture_and_the_projection():
    face = a_face_with_a_picture()
    full = PictureView(header(face), face, (200, 160)).render(np.zeros(len(NAMES)))
    half = PictureView(header(face), face, (100, 80)).render(np.zeros(len(NAMES)))
    small = cv2.resize(full, (100, 80), interpolation=cv2.INTER_AREA)
    assert half.shape == (80, 100, 3)
    assert np.abs(half.astype(int) - small.astype(int)).mean() < 3


def test_an_open_mouth_is_drawn_from_the_person_own_open_mouth():
    face = a_face_with_a_picture((400, 320), scale=140.0)
    index = mouth_vertices(face)
    place = Placement.from_matrix(face.picture.projection)
    corners = (place.apply(face.vertices[index]) * [1, -1, 1])[:, :2]
    red = np.zeros((12, 20, 3), np.uint8)
    red[..., 0] = 250
    points = (corners - corners.min(axis=0)) / np.ptp(corners, axis=0).clip(1e-6) * [19, 11]
    with_mouth = replace(face, picture=replace(face.picture, mouth=red, mouth_points=points))
    names = ("theta",)
    shut, opened = (PictureView(header(f, names), f, (400, 320)).render(np.array([20.0])) for f in (face, with_mouth))
    # (a pixel elsewhere may differ by a level: the texture's atlas holds the mouth too)
    cavity = np.abs(shut.astype(int) - opened).max(axis=2) > 2
    assert cavity.sum() > 100  # the opening shows the open mouth instead of the dark cavity
    assert np.all(opened[cavity][:, 0] > 200) and np.all(opened[cavity][:, 1:] < 60)
    # at rest the picture is its own to the edges (the texture holds more than the picture now)
    rest = PictureView(header(with_mouth, names), with_mouth, (400, 320)).render(np.array([0.0]))
    lips = np.any(PictureView(header(face, names), face, (400, 320)).render(np.array([0.0])) != rest, axis=2)
    np.testing.assert_array_equal(rest[~lips], face.picture.image[~lips])
    assert lips.sum() < 300  # the generic face's parted lips only
    # a face so large that its rings reach past half a picture side: its texture's border is at most half
    # the picture's larger side each way, and the person's open mouth is still drawn, the rest as without
    # it (the flat cavity had been drawn instead: liveportrait_d3, pcavs_Pose_Source)
    huge = replace(face, picture=replace(with_mouth.picture, image=with_mouth.picture.image[:160, :200],
                                         projection=Placement(140.0, np.eye(3), np.array([100.0, -80.0, 0])).matrix()))
    plain = replace(huge, picture=replace(huge.picture, mouth=None, mouth_points=None))
    assert SceneMesh(huge, huge.picture).texture.shape[:2] <= (160 + 200 + MOUTH_GAP + 12, 200 + 200)
    drawn, cavity = (PictureView(header(f, names), f, (200, 160)).render(np.array([20.0])) for f in (huge, plain))
    mouth = np.abs(drawn.astype(int) - cavity).max(axis=2) > 2
    assert mouth.sum() > 50 and np.all(drawn[mouth][:, 0] > 200) and np.all(drawn[mouth][:, 1:] < 60)


def test_looks_follow_what_the_face_has():
    face = a_face_with_a_picture()
    assert default_look(face) == "picture"
    assert default_look(replace(face, picture=None, texture=np.zeros((8, 8, 3), np.uint8))) == "face"
    assert default_look(BASE) == "shaded"
    with pytest.raises(InputError, match="reference picture"):
        open_view("picture", header(BASE), BASE, (64, 64))
    with pytest.raises(InputError, match="unknown look"):
        open_view("cartoon", header(BASE), BASE, (64, 64))


def test_a_face_without_a_picture_draws_as_before():
    names = ("theta", "rx", "ry", "rz")
    h = header(BASE, names)
    params = np.array([10.0, 2.0, 5.0, 0.0])
    np.testing.assert_array_equal(open_view("shaded", h, BASE, (96, 96)).render(params),
                                  FaceView(h, BASE, (96, 96)).render(params))


# A synthetic scene: a textured background, the generic face textured from a frame of the bundled
# clip drawn small in it (room for the rings), moved by known poses with the jaw opening.
SCENE = 320
FACE_SHARE = 0.3  # the face's height over the picture's


def scene_frames():
    face = BASE
    ok, frame = cv2.VideoCapture(str(GRID)).read()
    assert ok
    landmarks = FaceTracker().track(frame)
    texture = texture_from_frame(cv2.cvtColor(frame, cv2.COLOR_BGR2RGB), landmarks[:, :2], face.uv, face.faces, 512)
    y, x = np.mgrid[0:SCENE, 0:SCENE]
    background = np.dstack([90 + 60 * np.sin(x / 11.0), 110 + 50 * np.cos(y / 13.0),
                            120 + 40 * np.sin((x + y) / 17.0)]).astype(np.uint8)
    renderer = Renderer(face.faces, size=(SCENE, SCENE), uv=face.uv, texture=texture, mouth_faces=face.mouth_faces,
                        background=background)
    centre = 0.5 * (face.vertices.min(axis=0) + face.vertices.max(axis=0))
    camera = Camera.orthographic(1.0 / FACE_SHARE, eye=centre + [0, 0, 5.0], target=centre)
    deformer = Deformer(face)
    poses = [np.zeros(len(EXTENDED_PARAMS))]
    for k in range(1, 9):
        p = np.zeros(len(EXTENDED_PARAMS))
        p[0] = 6.0 * (k % 3)  # the jaw
        p[EXTENDED_PARAMS.index("ry")] = 6.0 * np.sin(k)
        p[EXTENDED_PARAMS.index("rz")] = 3.0 * np.cos(k)
        p[EXTENDED_PARAMS.index("tx")] = 0.08 * np.sin(0.7 * k)
        p[EXTENDED_PARAMS.index("ty")] = 0.05 * np.cos(0.9 * k)
        poses.append(p)
    frames = [renderer.render(deformer.deform_extended(p), camera)[0] for p in poses]
    return frames, background


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """(input RGB frames, the decoded RGB frames, the receiver's face, the stream's path, the face file's
    path) through fd-enroll, fd-send and fd-recv's sessions."""
    from facedeform.receiver.session import ReceiveSession
    from facedeform.receiver.transport import open_file
    from facedeform.sender.config import SendConfig
    from facedeform.sender.enroll import main as enroll
    from facedeform.sender.session import SendSession

    tmp = tmp_path_factory.mktemp("scene")
    frames, _ = scene_frames()
    for i, rgb in enumerate(frames):
        cv2.imwrite(str(tmp / f"{i:03d}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    path = tmp / "scene.fdface"
    assert enroll([str(tmp / "%03d.png"), "-o", str(path), "--frame", "0", "--motion", "0", "-q"]) == 0
    enrolled = Face.load(path).model
    # the same picture stored losslessly, so that the still background can be compared bit for bit
    lossless = replace(enrolled, picture=ReferencePicture(frames[0], enrolled.picture.projection))
    save_face_file(encode_face(lossless, picture_format=".png"), path)
    face = Face.load(path).model
    stream = tmp / "scene.fd"
    send = SendSession(str(tmp / "%03d.png"), SendConfig(layout="paper", neutral=0, smoothing=0.0),
                       face=Face.load(path))
    stream.write_bytes(b"".join(send.stream()))
    decoded, sizes = [], []

    class Sink:
        def write(self, image):
            decoded.append(image)

        def close(self):
            pass

    def open_sinks(fps, size):
        sizes.append(size)
        return [Sink()]

    receive = ReceiveSession(open_sinks, None, face)
    receive.run(open_file(str(stream), None))
    receive.close()
    assert receive.look == "picture" and sizes == [(SCENE, SCENE)]
    return frames, decoded, face, stream, path


def test_the_scene_decodes_one_frame_per_input_frame_at_its_size(scene):
    frames, decoded, *_ = scene
    assert len(decoded) == len(frames)
    assert all(d.shape == (SCENE, SCENE, 3) for d in decoded)


def test_the_background_past_the_rings_is_bit_exact(scene):
    frames, decoded, face, *_ = scene
    outer = SceneMesh(face, replace(face.picture, mouth=None))  # uv in the picture's own pixels
    ring = (outer.uv[-len(outer_loop(face.faces)):] * [SCENE, -SCENE] + [0, SCENE])  # outermost ring in pixels
    still = np.ones((SCENE, SCENE), np.uint8)
    cv2.fillPoly(still, [np.round(ring).astype(np.int32)], 0)
    still = cv2.erode(still, np.ones((5, 5), np.uint8)).astype(bool)  # a pixel's margin for the edge
    assert still.mean() > 0.2  # there is a background to compare
    for src, out in zip(frames, decoded):
        np.testing.assert_array_equal(out[still], src[still])


def test_the_face_follows_within_a_stated_error(scene):
    """Inside the face, mean absolute error under 12 grey levels in every frame (the synthetic head
    is lit, so turning it changes its shading, which a warp of the reference does not; and the
    tracker's landmarks are not exact); a frame drawn without moving the head is far worse."""
    frames, decoded, face, *_ = scene
    tracker = FaceTracker()
    worst_still = 0.0
    for src, out in zip(frames[1:], decoded[1:]):
        landmarks = tracker.track(cv2.cvtColor(src, cv2.COLOR_RGB2BGR))
        mask = np.zeros((SCENE, SCENE), np.uint8)
        cv2.fillConvexPoly(mask, cv2.convexHull(np.round(landmarks[:, :2]).astype(np.int32)), 1)
        inside = mask.astype(bool)
        error = np.abs(out[inside].astype(float) - src[inside]).mean()
        assert error < 12.0
        worst_still = max(worst_still, np.abs(frames[0][inside].astype(float) - src[inside]).mean())
    assert worst_still > 15.0


@pytest.mark.parametrize("look", ["picture", "face", "shaded", None])
def test_every_look_draws_every_frame_at_the_source_size(scene, tmp_path, look):
    from facedeform.experiment.clips import read_y4m
    from facedeform.receiver.cli import main

    frames, _, _, stream, path = scene
    out = tmp_path / "out.y4m"
    chosen = ["--look", look] if look else []
    assert main([str(stream), "--face", str(path), "-o", str(out), "-q", *chosen]) == 0
    decoded = read_y4m(out.read_bytes())
    assert len(decoded) == len(frames) and decoded[0].shape == (SCENE, SCENE, 3)
    assert main([str(stream), "--face", str(path), "-o", str(out), "-q", "--size", "64x48", *chosen]) == 0
    assert read_y4m(out.read_bytes())[0].shape == (48, 64, 3)


def test_a_bad_look_is_one_line(capsys):
    from facedeform.receiver.cli import main

    with pytest.raises(SystemExit) as info:
        main(["--look", "cartoon"])
    err = capsys.readouterr().err
    assert info.value.code == 2 and err.count("\n") == 1 and "invalid choice: 'cartoon'" in err


def test_the_picture_look_without_a_picture_is_one_line(scene, tmp_path, capsys):
    from facedeform.codec.face_file.format import read_face_bytes
    from facedeform.receiver.cli import main

    _, _, face, stream, path = scene
    bare = tmp_path / "bare.fdface"
    save_face_file(encode_face(replace(decode_face(read_face_bytes(path)), picture=None)), bare)
    assert main([str(stream), "--face", str(bare), "-o", str(tmp_path / "x.y4m"), "--look", "picture"]) != 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("fd-recv: ")


# The whole frame's motion (a camera's pan, zoom and roll): GLOBAL_PARAMS.
GLOBAL_NAMES = NAMES + GLOBAL_PARAMS


def test_global_motion_and_its_pixel_map_are_inverse_and_zero_is_none():
    reference = Placement(60.0, np.eye(3), np.array([100.0, -80.0, 0.0]))
    motion = np.array([0.1, -0.05, 0.03, 2.0])
    matrix = global_matrix(motion, reference, (200, 160))
    np.testing.assert_allclose(global_motion(matrix, reference, (200, 160)), motion, atol=1e-12)
    # the picture's centre moves by the shift alone (60 pixels a face height, y up), a corner also turns
    np.testing.assert_allclose(matrix @ [100.0, 80.0, 1.0], [106.0, 83.0], atol=1e-12)
    assert global_matrix(np.zeros(4), reference, (200, 160)) is None
    # the face ignores them: the receiver moves the picture
    deformer, full = Deformer(BASE), np.zeros(len(EXTENDED_PARAMS))
    full[slots(GLOBAL_PARAMS)] = motion
    np.testing.assert_array_equal(deformer.deform_extended(full), deformer.deform_extended(np.zeros(len(full))))


def test_the_picture_moves_by_the_global_motion_and_stays_bit_exact_without():
    face = a_face_with_a_picture()
    view = PictureView(header(face, GLOBAL_NAMES), face, (200, 160))
    rest = PictureView(header(face), face, (200, 160)).render(np.zeros(len(NAMES)))
    np.testing.assert_array_equal(view.render(np.zeros(len(GLOBAL_NAMES))), rest)
    motion = np.array([0.1, -0.05, 0.03, 2.0])
    moved = view.render(np.r_[np.zeros(len(NAMES)), motion])
    matrix = global_matrix(motion, Placement.from_matrix(face.picture.projection), (200, 160))
    expected = cv2.warpAffine(face.picture.image, matrix, (200, 160), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REPLICATE)
    np.testing.assert_array_equal(moved[:, :8], expected[:, :8])  # past the rings: the moved picture
    np.testing.assert_array_equal(view.render(np.zeros(len(GLOBAL_NAMES))), rest)  # and back, exactly
    half = PictureView(header(face, GLOBAL_NAMES), face, (100, 80)).render(np.r_[np.zeros(len(NAMES)), motion])
    small = cv2.resize(moved, (100, 80), interpolation=cv2.INTER_AREA)
    assert np.abs(half.astype(int) - small.astype(int))[:, :4].mean() < 4  # scaled with the output


def test_the_body_moves_by_its_own_shift_below_the_chin_only():
    face = a_face_with_a_picture()
    names = GLOBAL_NAMES + BODY_PARAMS
    view = PictureView(header(face, names), face, (200, 160))
    rest = PictureView(header(face), face, (200, 160)).render(np.zeros(len(NAMES)))
    np.testing.assert_array_equal(view.render(np.zeros(len(names))), rest)
    moved = view.render(np.r_[np.zeros(len(GLOBAL_NAMES)), 0.1, 0.05])  # 6 pixels right, 3 up
    body = BodyRegion.of(Placement.from_matrix(face.picture.projection), face.vertices)
    chin, low = int(body.chin), int(np.ceil(body.chin + body.ramp)) + 3
    shifted = cv2.warpAffine(face.picture.image, np.float64([[1, 0, 6], [0, 1, -3]]), (200, 160),
                             flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    # past the rings, on the left: above the chin the picture as it was, on the body the picture shifted
    np.testing.assert_array_equal(moved[:chin - 5, :4], rest[:chin - 5, :4])  # (its warp is computed coarse)
    np.testing.assert_array_equal(moved[low:-1, :4], shifted[low:-1, :4])  # (the last row: the border, rounded apart)
    np.testing.assert_array_equal(view.render(np.zeros(len(names))), rest)  # and back, exactly


def test_a_view_drawing_frame_after_frame_draws_what_a_fresh_view_draws():
    """The receiver draws only what changes: its rasteriser clears only the last frame's box, the
    background is warped again only when the camera's or the body's motion changes. Frame after
    frame, over a still camera and then a moving one (each motion held for a few frames), with the
    head and the jaw moving throughout, that is pixel for pixel what a view drawing each frame from
    nothing draws."""
    face = a_face_with_a_picture()
    names = GLOBAL_NAMES + BODY_PARAMS
    rng = np.random.default_rng(5)
    cameras = [np.zeros(6)] * 4 + [np.r_[0.02 * k, -0.01 * k, 0.01 * k, 0.5 * k, 0.0, 0.0] for k in (1, 1, 2)] \
        + [np.r_[0.04, -0.02, 0.02, 1.0, 0.05, 0.02]] * 2 + [np.zeros(6)]
    view = PictureView(header(face, names), face, (200, 160))
    for camera in cameras:
        head = np.r_[rng.uniform(0, 20), rng.normal(0, 4, 3), rng.normal(0, 0.03, 3)]  # theta, rotation, shift
        params = np.r_[head, camera]
        drawn = view.render(params)
        np.testing.assert_array_equal(drawn, PictureView(header(face, names), face, (200, 160)).render(params))


def test_absurd_body_shifts_from_a_stream_still_draw_a_picture():
    """A stream's body values far past any picture (its steps times the largest index) draw the
    picture's edges repeated, with the camera still or moving: no error, the picture's size."""
    face = a_face_with_a_picture()
    names = GLOBAL_NAMES + BODY_PARAMS
    view = PictureView(header(face, names), face, (200, 160))
    for body in ((1e6, -1e6), (-3e4, 2e5), (1e12, 1e12)):
        for motion in ((0.0, 0.0, 0.0, 0.0), (0.1, 0.05, 0.02, 3.0)):
            image = view.render(np.r_[np.zeros(len(NAMES)), motion, body])
            assert image.shape == (160, 200, 3) and image.dtype == np.uint8


def test_the_warp_map_is_the_exact_inverse_of_the_motion():
    """The map cv2.remap reads, computed coarse and scaled up: the inverse of the camera's motion at
    every pixel (to 1e-3 pixels), and of the body's shift where the body moves fully."""
    c, s = 1.02 * np.cos(0.05), 1.02 * np.sin(0.05)
    still = np.array([[c, s, 3.3], [-s, c, -2.1]])
    body = BodyRegion(150.0, 30.0)
    for size, zoom in (((256, 256), (1.0, 1.0)), ((250, 190), (0.75, 0.74))):
        y, x = np.mgrid[0:size[1], 0:size[0]]
        exact = (np.stack([x / zoom[0], y / zoom[1]], -1) - still[:, 2]) @ np.linalg.inv(still[:, :2]).T
        maps = np.stack(warp_map(size, zoom, body, (still, None)), -1)
        assert np.abs(maps - exact).max() < 1e-3
        maps = np.stack(warp_map(size, zoom, body, (still, np.array([4.0, -3.0]))), -1)
        full = exact[..., 1] > 190  # rows fully on the body
        np.testing.assert_allclose(maps[full] + [4.0, -3.0], exact[full], atol=1e-3)
        np.testing.assert_allclose(maps[exact[..., 1] < 145], exact[exact[..., 1] < 145], atol=1e-3)


def a_textured_scene(size=256, seed=4):
    """A face model placed in the middle of a picture of random blobs (corners everywhere)."""
    rng = np.random.default_rng(seed)
    image = np.full((size, size, 3), 120, np.uint8)
    for _ in range(400):
        centre = tuple(int(v) for v in rng.integers(0, size, 2))
        cv2.circle(image, centre, int(rng.integers(2, 9)), tuple(int(v) for v in rng.integers(0, 255, 3)), -1)
    place = Placement(size * 0.3, np.eye(3), np.array([size / 2, -size / 2, 0.0]))
    return replace(BASE, picture=ReferencePicture(image, place.matrix()))


def landmarks_of(face, placement: Placement) -> np.ndarray:
    """(468, 3) tracker-like landmarks (pixels, y down, z away from the camera) of the face placed so."""
    return placement.apply(face.vertices) * [1.0, -1.0, -1.0]


def test_the_sender_measures_a_known_global_motion():
    face = a_textured_scene()
    measure = GlobalMotion(face.picture, face.vertices)
    reference = measure.reference
    landmarks = landmarks_of(face, reference)
    bgr = cv2.cvtColor(face.picture.image, cv2.COLOR_RGB2BGR)
    np.testing.assert_array_equal(measure.measure(bgr, landmarks), np.zeros(6))  # still: exactly zero
    for motion in ([0.06, -0.04, 0.0, 0.0], [0.02, 0.03, 0.04, 1.5], [-0.1, 0.05, -0.05, -3.0]):
        matrix = global_matrix(np.array(motion), reference, (256, 256))
        frame = cv2.warpAffine(bgr, matrix, (256, 256), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        got = measure.measure(frame, landmarks)[:4]
        # within a quarter of a pixel at the picture's corners (shift in face heights of 77 pixels)
        corners = np.array([[0, 0], [255, 0], [0, 255], [255, 255]], float)
        back = global_matrix(got, reference, (256, 256))
        error = np.abs(corners @ back[:, :2].T + back[:, 2] - (corners @ matrix[:, :2].T + matrix[:, 2]))
        assert error.max() < 0.25, (motion, got)
    # a frame of another size is measured as if scaled to the picture's
    big = cv2.resize(frame, (512, 512), interpolation=cv2.INTER_LINEAR)
    np.testing.assert_allclose(measure.measure(big, landmarks * 2)[:4], got, atol=0.01)


def shoulders_on_a_wall(seed=5, size=256):
    """(GlobalMotion, landmarks, a function that measures the body shifted by (dx, dy) pixels as
    body_shift gives it): a plain wall, and corners only on the speaker's shoulders (blobs along the
    bottom, wider than the face)."""
    image = np.full((size, size, 3), 120, np.uint8)
    rng = np.random.default_rng(seed)
    for _ in range(200):
        centre = (int(rng.integers(0, size)), int(rng.integers(int(0.8 * size), size)))
        cv2.circle(image, centre, int(rng.integers(2, 6)), tuple(int(v) for v in rng.integers(0, 255, 3)), -1)
    place = Placement(size * 0.3, np.eye(3), np.array([size / 2, -0.4 * size, 0.0]))
    face = replace(BASE, picture=ReferencePicture(image, place.matrix()))
    measure = GlobalMotion(face.picture, face.vertices)
    landmarks = landmarks_of(face, measure.reference)
    bgr = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)

    def body_at(dx, dy):
        moved = cv2.warpAffine(bgr, np.float32([[1, 0, dx], [0, 1, dy]]), (size, size),
                               borderMode=cv2.BORDER_REPLICATE)  # the body shifts, the wall stays
        return body_shift(measure.measure(moved, landmarks), measure.reference)

    return measure, body_at


def test_shoulders_that_move_on_a_plain_wall_are_not_a_moving_camera():
    """The bundled clip's case: a plain wall, and corners only on the speaker's shoulders (beside
    and below the face): they move with the person, so the camera stays still, and the body's own
    shift is measured instead."""
    measure, body_at = shoulders_on_a_wall()
    assert not measure.usable and measure.body
    assert body_at(0, 0) is None
    np.testing.assert_allclose(body_at(4, -3), [4, -3], atol=0.1)


def test_a_body_that_left_the_picture_is_found_again():
    """Shoulders moved far down (most of their corners out of the picture, the rest too few to
    measure) keep the last shift; back in place they are found again, exactly still."""
    _, body_at = shoulders_on_a_wall(seed=6)
    np.testing.assert_allclose(body_at(5, 3), [5, 3], atol=0.1)
    np.testing.assert_allclose(body_at(5, 60), [5, 3], atol=0.1)  # gone below the edge: the last shift
    assert body_at(0, 0) is None  # back: from no shift, found again


def test_a_large_picture_is_followed_at_a_fraction_of_its_size():
    """A 1920-pixel picture is followed at half size, its motion given in its own pixels: within
    half a pixel (a quarter of a working one) at its corners; still is still."""
    size = 1920
    face = a_textured_scene(size)
    measure = GlobalMotion(face.picture, face.vertices)
    landmarks = landmarks_of(face, measure.reference)
    bgr = cv2.cvtColor(face.picture.image, cv2.COLOR_RGB2BGR)
    np.testing.assert_array_equal(measure.measure(bgr, landmarks), np.zeros(6))
    matrix = global_matrix(np.array([0.03, -0.02, 0.01, 0.5]), measure.reference, (size, size))
    frame = cv2.warpAffine(bgr, matrix, (size, size), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    back = global_matrix(measure.measure(frame, landmarks)[:4], measure.reference, (size, size))
    corners = np.array([[0, 0], [size - 1, 0], [0, size - 1], [size - 1, size - 1]], float)
    error = np.abs(corners @ back[:, :2].T + back[:, 2] - (corners @ matrix[:, :2].T + matrix[:, 2]))
    assert error.max() < 0.5


def test_a_plain_background_carries_no_global_motion():
    from facedeform.sender.analysis import picture_names

    face = a_textured_scene()
    assert GlobalMotion(face.picture, face.vertices).usable
    plain = replace(face.picture, image=np.full_like(face.picture.image, 90))
    assert not GlobalMotion(plain, face.vertices).usable
    assert picture_names(("theta",), face)[-4:] == GLOBAL_PARAMS
    assert picture_names(("theta",), face, moving=False) == ("theta", "tx", "ty", "tz")
    assert picture_names(("theta",), face, moving=False, body=True) == ("theta", "tx", "ty", "tz") + BODY_PARAMS


def test_ring_weights_follow_what_moves_with_the_head():
    """Frames where the picture around the face moves with the head (hair) give weights near 1 there;
    frames where only the face moves (a wall) near 0; the outermost ring stays put either way. The
    picture far from the face stays still (a camera that moved everything would be the camera's
    motion, which the weights count from)."""
    face = a_textured_scene()
    reference = Placement.from_matrix(face.picture.projection)
    bgr = cv2.cvtColor(face.picture.image, cv2.COLOR_RGB2BGR)
    shifts = [np.array([dx, dy]) for dx, dy in ((6, 0), (-6, 2), (0, -6), (4, 4), (-4, -5))] * 30
    near = face_mask(landmarks_of(face, reference)[:, :2], (256, 256), below=False)[..., None] == 0

    def frames(moving):
        for shift in shifts:
            placed = Placement(reference.scale, reference.rotation, reference.shift + [shift[0], -shift[1], 0.0])
            moved = cv2.warpAffine(bgr, np.float64([[1, 0, shift[0]], [0, 1, shift[1]]]), (256, 256),
                                   borderMode=cv2.BORDER_REFLECT)
            yield np.where(near, moved, bgr) if moving else bgr, landmarks_of(face, placed)

    def weights(moving):
        measured = RingWeights(face)
        for frame, landmarks in frames(moving):
            measured.add(frame, landmarks)
        return measured.weights().reshape(len(RINGS), -1)

    hair, wall = weights(True), weights(False)
    np.testing.assert_array_equal(hair[-1], 0.0)
    np.testing.assert_array_equal(wall[-1], 0.0)
    assert hair[0].mean() > 0.9 and wall[:-1].mean() < 0.1
