"""Decoded parameters -> pixels: deform the base face, pose the head, render.

Three looks: "shaded", the paper's Phong-shaded face; "face", the person's
textured face alone (FaceView); "picture", the person's whole reference
picture warped by the moving face (PictureView, codec/render/picture.py).
"""

from collections import deque

import numpy as np

from facedeform.codec.model.deform import Deformer
from facedeform.codec.model.face_model import BaseFace, mouth_vertices
from facedeform.codec.render.camera import Camera
from facedeform.codec.render.eyelids import Eyelids
from facedeform.codec.render.frame_video import HELD, VideoLayer, drawn_size, shrunk
from facedeform.codec.render.mouth_interior import LOWER_LIP, UPPER_LIP
from facedeform.codec.render.picture import (
    Placement,
    SceneMesh,
    body_shift,
    face_texture,
    frame_placement,
    global_matrix,
    moved_body,
    warp_map,
)
from facedeform.codec.render.render import UNLIT, Renderer
from facedeform.common.errors import BitstreamError, InputError
from facedeform.common.parameters import BODY_PARAMS, EXTENDED_PARAMS, GLOBAL_PARAMS, POSE_PARAMS, slots
from facedeform.common.stages import View
from facedeform.protocol.stream import Header

FIELD_OF_VIEW = 20.0  # degrees: a portrait lens, little perspective distortion
FRAMING = 1.35  # the view's height over the face's height
BACKGROUND = (38, 42, 48)  # a dark slate that sets off skin without the harshness of black


def portrait_camera(face: BaseFace) -> Camera:
    """A perspective camera looking at the base face from the front, the face filling the view's height."""
    lo, hi = face.vertices.min(axis=0), face.vertices.max(axis=0)
    centre = (lo + hi) / 2
    distance = FRAMING * (hi[1] - lo[1]) / 2 / np.tan(np.radians(FIELD_OF_VIEW / 2)) + hi[2] - centre[2]
    return Camera.perspective(FIELD_OF_VIEW, eye=centre + [0, 0, distance], target=centre)


LOOKS = ("picture", "face", "shaded")
DEFAULT_SIZE = (512, 512)


def default_look(face: BaseFace) -> str:
    """The most the face allows: its whole picture, else its textured face, else the shaded face."""
    return "picture" if face.picture is not None else "face" if face.texture is not None else "shaded"


def output_size(header: Header, face: BaseFace, look: str) -> tuple[int, int]:
    """(width, height) by default: the source's (from the header), else for the picture look the
    reference picture's, else DEFAULT_SIZE."""
    if header.width and header.height:
        return header.width, header.height
    if look == "picture" and face.picture is not None:
        return face.picture.image.shape[1], face.picture.image.shape[0]
    return DEFAULT_SIZE


def open_view(look: str, header: Header, face: BaseFace, size: tuple[int, int], check_id: bool = True) -> View:
    """The view drawing ``look`` (one of LOOKS) of ``face``; InputError if the face cannot show it."""
    if look == "picture":
        if face.picture is None:
            raise InputError("--look picture needs a face model with a reference picture (fd-enroll "
                             "without --no-picture)")
        return PictureView(header, face, size, check_id)
    if look not in LOOKS:
        raise InputError(f"unknown look {look!r}: choose from {', '.join(LOOKS)}")
    return FaceView(header, face, size, check_id, textured=look == "face")


def face_renderer(face: BaseFace, size: tuple[int, int], textured: bool = True) -> Renderer:
    """The receiver's look: the default lights and a dark mouth; a personal model (with a
    texture) shows its own eyes from the photo, the plain shaded face gets painted ones."""
    texture, uv = face_texture(face)
    textured = textured and texture is not None
    return Renderer(face.faces, size=size, mouth_faces=face.mouth_faces,
                    eye_faces=None if textured else face.eye_faces, background=BACKGROUND,
                    uv=uv if textured else None, texture=texture if textured else None)


class FaceView:
    """Renders one (H, W, 3) uint8 RGB image per parameter vector of the stream's layout.

    A layout is any list of names from ``common.parameters.EXTENDED_PARAMS``; the
    parameters a stream leaves out stay at rest. ``check_id=False`` draws a
    face other than the one the stream names (the receiver's fallback when an
    in-band model was lost); ``textured=False`` shades the mesh as the paper does.
    """

    def __init__(self, header: Header, face: BaseFace, size: tuple[int, int], check_id: bool = True,
                 textured: bool = True) -> None:
        if check_id and header.face_id != face.content_id:
            raise BitstreamError(f"the stream was made for face model {header.face_id[:12]}, "
                                 f"this receiver holds {face.content_id[:12]} (give the model with --face FILE)")
        unknown = [n for n in header.names if n not in EXTENDED_PARAMS]
        if unknown or len(set(header.names)) != len(header.names):
            raise BitstreamError(f"unknown parameter layout: {', '.join(header.names)}")
        self._slots = slots(header.names)
        self._f3_with_jaw = header.f3_with_jaw
        self._deformer = Deformer(face, header.rule)
        self._made = (header, face, check_id)  # what a view of another size is made of
        self.size = size
        self._setup(face, size, textured)

    def _setup(self, face: BaseFace, size: tuple[int, int], textured: bool) -> None:
        self._renderer = face_renderer(face, size, textured)
        self._camera = portrait_camera(face)

    def _full(self, params: np.ndarray) -> np.ndarray:
        full = np.zeros(len(EXTENDED_PARAMS))
        full[self._slots] = params
        return full

    def render(self, params: np.ndarray, seq: int | None = None) -> np.ndarray:
        """The face of one frame (``seq``: its number, which only the whole picture uses)."""
        full = self._full(params)
        vertices = self._deformer.deform_extended(full, f3_with_jaw=self._f3_with_jaw)
        irises = self._deformer.iris(full)[0]
        return self._renderer.image(vertices, self._camera, irises)


_POSE = slots(POSE_PARAMS)
_GLOBAL = slots(GLOBAL_PARAMS)
_BODY = slots(BODY_PARAMS)
#: A frame's motion of the picture around the face: (the global motion's (2, 3) pixel map, the body's shift in
#: pixels), each None for none.
Motion = tuple[np.ndarray | None, np.ndarray | None]
_STILL: Motion = (None, None)


class PictureView(FaceView):
    """The whole picture: the reference picture, warped by the face deformed with the expression
    and placed by the head pose relative to the reference (codec/render/picture.py), at ``size`` (the
    picture and its projection scaled to it), the picture moved by the frame's global motion (the
    camera's) and its body by the body's own shift. Unlit: the picture's own light.

    The picture layer (:attr:`layer`, codec/render/frame_video.py) draws the real frame as a small video
    where the sender found it nearer the frame than this picture (a turned head's far side, a
    shirt, the background a camera uncovers); the sender runs this same view and layer on what it
    sends (sender/picture_layer.py), so both ends draw the same pixels.
    """

    def _setup(self, face: BaseFace, size: tuple[int, int], textured: bool) -> None:
        import cv2

        picture = face.picture
        if picture is None:
            raise InputError("this face model has no reference picture to draw")
        height, width = picture.image.shape[:2]
        self._scene = SceneMesh(face, picture)
        w, h = size
        sx, sy = w / width, h / height
        self._scale = np.array([sx, sy, np.sqrt(sx * sy)])
        background = picture.image if (w, h) == (width, height) else \
            cv2.resize(picture.image, (w, h), interpolation=cv2.INTER_AREA if sx * sy < 1 else cv2.INTER_LINEAR)
        self._picture, self._picture_size, self._still = picture.image, (width, height), background
        self.picture_size = self._picture_size
        self._moved: Motion = _STILL  # the motion the renderer's background has
        self._renderer = Renderer(self._scene.triangles, size=size, material=UNLIT, lights=(), background=background,
                                  uv=self._scene.uv, texture=self._scene.texture, mouth_faces=self._scene.mouth_faces)
        self._camera = _picture_camera(size)
        self._seq = -1
        self.layer = VideoLayer(self._picture_size, self._made[0].ahead)
        self._lips = mouth_vertices(face)
        self._positions: np.ndarray | None = None  # the scene's vertices in the last picture drawn
        self._lids = Eyelids(face, self._scene.rest_pixels, self._picture_size)
        self._shut: tuple[float, ...] = (0.0, 0.0)  # how far each eye is closed (codec/render/eyelids.py)
        self._open = 1.0  # how open the mouth is, against the person's open mouth (codec/render/mouth_interior.py)
        #: which of the mouth opening's triangles the renderer draws from the reference picture (SceneMesh.slivers)
        self._slivers = np.zeros(len(self._scene.opening), bool)
        #: (frame, scene vertex positions, motion) of the last frames drawn: where the picture
        #: layer's video frames were, to carry them (:meth:`carry`)
        self._drawn: deque[tuple[int, np.ndarray, Motion]] = deque(maxlen=HELD)
        #: the same of frames not drawn yet (:meth:`expect`): where a video frame the layer draws the frames
        #: before it from was
        self._expected: deque[tuple[int, np.ndarray, Motion]] = deque(maxlen=HELD)
        self._carrier: Renderer | None = None  # the scene textured by a video frame
        self._carried: tuple[np.ndarray, int] | None = None  # (the video frame it is textured by, its frame)
        self._carried_motion: tuple[Motion, Motion] | None = None  # (then, now) of the carrier's background
        #: (video frame, its frame, the entry of the frame drawn last, the carried picture): the sender
        #: asks for the same one twice in a frame (to choose the blocks, then to draw)
        self._carry_last: tuple[np.ndarray, int, tuple, np.ndarray] | None = None
        self._reference: PictureView | None = None  # draws the model's picture a video frame is coded from
        #: (frame, parameters, the model's picture, the same at the video's size, its entry of _drawn) drawn
        #: to decode a video frame, which :meth:`render` then draws over instead of drawing it again (a
        #: view of the picture's own size): the last, and those after frames still waiting to be drawn
        self._decoded: deque[tuple[int, np.ndarray, np.ndarray, np.ndarray, tuple]] = deque(maxlen=HELD)

    def advance(self, params: np.ndarray, seq: int, exact: bool = True) -> bool:
        """Decodes the picture layer's payloads of frame ``seq`` (before :meth:`render` draws it, and
        whether it is drawn or not), whose parameters are ``params``, as sent unless not ``exact`` (a
        frame concealed: a payload of it cannot be decoded as the sender did). False if one was lost."""
        return self.layer.decode_due(seq, (lambda size: self._decoded_from(params, seq, size)) if exact else None)

    def _decoded_from(self, params: np.ndarray, seq: int, size: tuple[int, int]) -> np.ndarray:
        """:meth:`reference_picture`, from this view's own drawing of the frame where it is drawn at
        that size (kept for :meth:`render`): the drawing is the same whatever was drawn before (a
        receiver's reference view draws only the video's frames)."""
        if self.size != drawn_size(self._picture_size, size):
            self.expect(params, seq)
            return self.reference_picture(params, seq, size)
        model = self.model_picture(params, seq)
        small = shrunk(model, size)
        self._decoded.append((seq, params.copy(), model, small, self._drawn[-1]))
        return small

    def expect(self, params: np.ndarray, seq: int) -> None:
        """Where the scene is in frame ``seq`` (parameters ``params``), not drawn yet: the picture layer
        draws the frames before a video frame from it too (frame_video.VideoLayer.draw)."""
        positions, motion, _ = self._placed(self._full(params))
        self._expected.append((seq, positions, motion))

    def reference_picture(self, params: np.ndarray, seq: int, size: tuple[int, int]) -> np.ndarray:
        """The model's picture of frame ``seq`` at ``size`` (w, h): what the layer's video frame of ``seq``
        is coded from, the same at both ends whatever this view's size: drawn at
        :func:`~facedeform.codec.render.frame_video.drawn_size` by a view of its own and shrunk."""
        drawn = drawn_size(self._picture_size, size)
        if self._reference is None or self._reference.size != drawn:
            self._reference = PictureView(*self._made[:2], drawn, self._made[2])
        return shrunk(self._reference.model_picture(params, seq), size)

    def render(self, params: np.ndarray, seq: int | None = None, shape: np.ndarray | None = None) -> np.ndarray:
        """The picture of frame ``seq`` (None: the one after the last), the picture layer's as it
        holds for that frame; ``shape``: a (468, 3) pose-free face (base-face units) to draw
        instead of the one the parameters' expression deforms (the expression benchmark's oracle,
        the tracked face itself), placed by the parameters' head pose and global motion."""
        seq = self._seq + 1 if seq is None else seq
        self.advance(params, seq)  # a payload not yet decoded (the receiver's session decodes first)
        decoded = self._decoded
        while decoded and decoded[0][0] < seq:
            decoded.popleft()
        if shape is None and decoded and decoded[0][0] == seq and np.array_equal(decoded[0][1], params):
            _, _, model, small, entry = decoded.popleft()
            self._seq, self._positions = seq, entry[1]
            self._drawn.append(entry)  # placed last again, for the carry
            return self.layer.draw(seq, model, self.carry, small)
        return self.layer.draw(seq, self.model_picture(params, seq, shape), self.carry)

    def model_picture(self, params: np.ndarray, seq: int | None = None, shape: np.ndarray | None = None
                      ) -> np.ndarray:
        """What :meth:`render` draws before the picture layer: the model's picture alone."""
        self.place(params, seq, shape)
        return self.placed_picture()

    def placed_picture(self) -> np.ndarray:
        """The model's picture of the frame last placed (:meth:`place`)."""
        assert self._positions is not None, "place a frame first"
        return self._renderer.image(self._positions * self._scale, self._camera)

    def place(self, params: np.ndarray, seq: int | None = None, shape: np.ndarray | None = None) -> None:
        """Everything :meth:`model_picture` does but the drawing: the frame's place in the history
        :meth:`carry` and :attr:`mouth_box` go by, and the texture's lids and mouth for it (a sender
        that chooses on a smaller view draws this one only when its picture is asked for)."""
        self._seq = self._seq + 1 if seq is None else seq
        positions, motion, deformed = self._placed(self._full(params), shape)
        self._move_background(motion)
        shut = self._lids.weights(deformed)
        interior = self._scene.interior
        opening = 1.0 if interior is None else interior.ratio(positions[UPPER_LIP], positions[LOWER_LIP])
        if shut != self._shut:  # only the eyes' box of the texture changes
            self._shut = shut
            x0, y0, _, _ = self._lids.box
            x, y = self._scene.picture_at
            self._patch(x + x0, y + y0, self._lids.region(self._picture, shut))
        if opening != self._open and interior is not None:
            self._open = opening
            self._patch(0, self._scene.mouth_row, interior.drawn(opening))
        slivers = self._scene.slivers(positions)
        if not np.array_equal(slivers, self._slivers):
            self._slivers = slivers
            scene = self._scene
            drawn = np.where(slivers[:, None], scene.shut, scene.triangles[scene.opening])
            self._renderer.set_faces(scene.opening, drawn, scene.mouth_faces[scene.opening] & ~slivers)
        self._positions = positions
        self._drawn.append((self._seq, positions, motion))

    @property
    def placing(self) -> tuple[Placement, np.ndarray]:
        """(the reference picture's placement of the face, the head's pivot): what the head pose is relative to."""
        return self._scene.reference, self._scene.pivot

    def carry(self, video: np.ndarray, since: int) -> np.ndarray:
        """The picture layer's video frame ``video`` (any size), which shows frame ``since``, moved to the
        frame last drawn, at the video's size (the video has no finer detail to move): the scene mesh
        drawn where it is now, textured by the video where the mesh was then, and past the rings the
        video moved by the change of the global motion. The model's motion carries the video between
        its frames (a held frame no longer lags a turning head or a moving mouth); at frame ``since``
        itself it is the video."""
        drawn = self._drawn[-1]
        last = self._carry_last
        if last is not None and last[0] is video and last[1] == since and last[2] is drawn:
            return last[3]
        out = self._carry(video, since, drawn)
        out.flags.writeable = False  # handed out again
        self._carry_last = video, since, drawn, out
        return out

    def _carry(self, video: np.ndarray, since: int, drawn: tuple[int, np.ndarray, Motion]) -> np.ndarray:
        (pw, ph), (vw, vh) = self._picture_size, video.shape[1::-1]
        _, now, now_motion = drawn
        # (a frame neither drawn here nor expected, its parameters lost: the video as it is)
        _, then, then_motion = next((d for d in reversed(self._drawn) if d[0] == since), None) or next(
            (d for d in reversed(self._expected) if d[0] == since), drawn)
        if then is now:  # the video's own frame: nothing to carry
            return video
        scale = np.array([vw / pw, vh / ph, np.sqrt(vw * vh / (pw * ph))])
        carrier = self._carrier
        if carrier is None or self._carried is None or self._carried[0] is not video or self._carried[1] != since:
            pixels = (then * scale)[:, :2] * [1.0, -1.0]
            uv = np.column_stack([pixels[:, 0] / vw, 1.0 - pixels[:, 1] / vh])
            if carrier is None or carrier.size != (vw, vh):
                carrier = Renderer(self._scene.triangles, size=(vw, vh), material=UNLIT, lights=(),
                                   background=video, uv=uv, texture=video)  # the video's own mouth
            else:
                carrier.retexture(uv, video)
            self._carrier, self._carried, self._carried_motion = carrier, (video, since), None
        if self._carried_motion is None or not _same((then_motion, now_motion), self._carried_motion):
            self._carried_motion = then_motion, now_motion
            carrier.set_background(self._moved_video(video, then_motion, now_motion))
        return carrier.image(now * scale, _picture_camera((vw, vh)))

    @property
    def mouth_box(self) -> tuple[float, float, float, float]:
        """The mouth's box (x0, y0, x1, y1) in the picture's pixels in the last picture drawn, with a
        quarter of its width around (the picture layer leaves it to the model where it can); all 0
        before the first."""
        if self._positions is None:
            return 0.0, 0.0, 0.0, 0.0
        lips = self._scene.pixels(self._positions)[self._lips]
        reach = 0.25 * (lips[:, 0].max() - lips[:, 0].min())
        (x0, y0), (x1, y1) = lips.min(axis=0) - reach, lips.max(axis=0) + reach
        return float(x0), float(y0), float(x1), float(y1)

    def _moved_video(self, video: np.ndarray, then: Motion, now: Motion) -> np.ndarray:
        """The picture layer's ``video`` frame, which shows a frame whose motion was ``then``, moved as
        the picture around the face moves to ``now``."""
        import cv2

        (pw, ph), (vw, vh) = self._picture_size, video.shape[1::-1]
        zoom = (vw / pw, vh / ph)
        if then[1] is None and now[1] is None:
            motion = _between(then[0], now[0], zoom)
            return video if np.array_equal(motion, _IDENTITY) else cv2.warpAffine(
                video, motion, (vw, vh), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        maps = warp_map((vw, vh), zoom, self._scene.body, now, then)
        return cv2.remap(video, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def _placed(self, full: np.ndarray, shape: np.ndarray | None = None
                ) -> tuple[np.ndarray, Motion, np.ndarray]:
        """(scene vertex positions in picture axes, the frame's motion, the pose-free deformed face)
        for ``full`` (its expression drawn as ``shape`` if given)."""
        pose = full[_POSE].copy()
        expression = full.copy()
        expression[_POSE] = 0.0
        deformed = self._deformer.deform_extended(expression, f3_with_jaw=self._f3_with_jaw) if shape is None \
            else np.asarray(shape, dtype=np.float64)
        frame = frame_placement(self._scene.reference, pose, self._scene.pivot)
        still = global_matrix(full[_GLOBAL], self._scene.reference, self._picture_size)
        shift = body_shift(full[_BODY], self._scene.reference)
        return self._scene.positions(deformed, frame, still, shift), (still, shift), deformed

    def _patch(self, x: int, y: int, image: np.ndarray) -> None:
        self._renderer.patch_texture(x, y, image)

    def _move_background(self, motion: Motion) -> None:
        """The picture moved by ``motion`` (none: the picture as it is, bit-exact) as the renderer's
        background, warped once per change of the motion."""
        import cv2

        if _same(motion, self._moved):
            return
        self._moved = motion
        still, shift = motion
        if still is None and shift is None:
            self._renderer.set_background(self._still)
            return
        w, h = self.size
        zoom = (w / self._picture_size[0], h / self._picture_size[1])
        if shift is None:
            self._renderer.set_background(cv2.warpAffine(self._picture, np.diag(zoom) @ still, (w, h),
                                                         flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE))
            return
        if still is None:
            self._renderer.set_background(moved_body(self._picture, self._still, zoom, self._scene.body, shift))
            return
        maps = warp_map((w, h), zoom, self._scene.body, motion)
        self._renderer.set_background(cv2.remap(self._picture, *maps, cv2.INTER_LINEAR,
                                                borderMode=cv2.BORDER_REPLICATE))


_IDENTITY = np.eye(2, 3)


def _same(a, b) -> bool:
    """Whether two motions (or tuples of them) are the same: None only equals None."""
    if isinstance(a, tuple):
        return isinstance(b, tuple) and len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return a is b if a is None or b is None else np.array_equal(a, b)


def _between(then: np.ndarray | None, now: np.ndarray | None, zoom: tuple[float, float]) -> np.ndarray:
    """(2, 3) pixel map from a frame whose global motion was ``then`` to one whose is ``now`` (each a
    (2, 3) map from the reference picture, None: none), in pixels ``zoom`` (x, y) times the picture's."""
    if (then is None and now is None) or (then is not None and now is not None and np.array_equal(then, now)):
        return _IDENTITY

    def square(m: np.ndarray | None) -> np.ndarray:
        full = np.eye(3)
        if m is not None:
            full[:2] = m
        return full

    scale = np.diag([*zoom, 1.0])
    return (scale @ square(now) @ np.linalg.inv(square(then)) @ np.linalg.inv(scale))[:2]


def _picture_camera(size: tuple[int, int]) -> Camera:
    """The orthographic view of picture axes (x right, y up) onto ``size`` pixels; depth far from every vertex."""
    w, h = size
    reach = 8.0 * max(w, h)
    return Camera.orthographic(h, eye=(w / 2, -h / 2, reach), target=(w / 2, -h / 2, 0.0), near=1.0, far=2 * reach)
