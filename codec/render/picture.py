"""The whole picture: the person's reference picture, warped by the moving face mesh.

Geometry lives in *picture axes*: pixels, x right, y up (minus the picture's
row), z toward the viewer. A :class:`Placement` (a similarity) puts the face
model there; the reference picture's placement comes with the face file, and
each frame's is the reference's composed with the head pose the stream sends
(:func:`relative_pose` at the sender, :func:`frame_placement` at the receiver,
its inverse). The :class:`SceneMesh` is the face mesh plus rings of vertices
around its outer boundary, textured by the reference picture itself: the face
moves fully, the rings less and less outward, the outermost not at all, and
past it the picture stays exactly as it was.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from facedeform.codec.model.face_model import BaseFace, ReferencePicture, mouth_vertices
from facedeform.codec.model.head_pose import head_pivot, rotation_from_vector, rotation_vector
from facedeform.codec.render.mouth_interior import MouthInterior

#: How far the receiver's camera is from the face (base-face units), to turn scale changes into
#: depth: tz = VIEW_DISTANCE * (1 - 1 / s) for a head s times its reference size.
VIEW_DISTANCE = 3.9
#: Rings around the face's outer boundary, as multiples of the boundary's distance from the face
#: centre in the reference picture; the last one stays put.
RINGS = (1.2, 1.5, 2.0, 2.8)
#: How far each ring lies behind the boundary per unit of radius past it, in face heights: a
#: turned head hides the ring behind it (Z-buffer), never the other way round.
RING_DEPTH = 0.5
#: Above the face centre, rings out to this radius move fully with the head (hair); below, the
#: fall-off starts at the face (neck and shoulders do not turn with it).
HAIR_START = 1.3
MOUTH_GAP = 4  # rows between the pictures and the open mouth below them in the texture
#: A triangle of the mouth opening less than this many of the reference picture's pixels across (its
#: smallest height) is drawn from the picture where it lies, the lips' line at rest, not as the open mouth
#: or the cavity: such a sliver hits a pixel's centre here and there, and drew lips all but closed as a
#: dashed black line that the tracker read as parted lips (lipnet_bbaf2n: the decoded mouth's swing 0.82
#: of the speaker's with none, 0.91 / 0.88 / 0.89 with slivers below 1, 1.5 and 2.5 pixels;
#: pcavs_Pose_Source 0.84, 0.84 / 0.85 / 0.83, its correlation 0.83 to 0.85 at 1.5). In the picture's
#: pixels, not a drawing's: every view of a frame, whatever its size, draws the same mouth.
SLIVER = 1.5
#: The body (the picture below the chin, across its width: neck, shoulders, torso) moves by its own
#: shift (BODY_PARAMS), fully from BODY_START face heights below the chin in the reference picture,
#: rising smoothly (a smoothstep) from the chin; above the chin it does not move at all.
BODY_START = 0.1
BODY_GRID = 4  # pixels per point of the body's warp, which is smooth: computed coarse, scaled up
_FLIP = np.array([1.0, -1.0, 1.0])  # picture axes <-> (pixel x, pixel y down, depth)


@dataclass(frozen=True)
class Placement:
    """``picture = scale * model @ rotation.T + shift``: model space to picture axes."""

    scale: float
    rotation: np.ndarray  # (3, 3)
    shift: np.ndarray  # (3,)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) model points -> (n, 3) picture-axes points."""
        return self.scale * np.asarray(points, dtype=np.float64) @ self.rotation.T + self.shift

    def matrix(self) -> np.ndarray:
        """(3, 4) projection of homogeneous model points to (pixel x, pixel y down, depth toward the viewer)."""
        return _FLIP[:, None] * np.column_stack([self.scale * self.rotation, self.shift])

    @classmethod
    def from_matrix(cls, matrix: np.ndarray) -> Placement:
        """The placement whose :meth:`matrix` is ``matrix``; ValueError unless it is a finite similarity."""
        m = np.asarray(matrix, dtype=np.float64)
        if m.shape != (3, 4) or not np.all(np.isfinite(m)):
            raise ValueError("the projection is not a finite 3x4 matrix")
        linear = _FLIP[:, None] * m[:, :3]
        scale = float(np.cbrt(np.linalg.det(linear)))
        if not scale > 0:
            raise ValueError("the projection is not a rotation and scale")
        rotation = linear / scale
        if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-4):
            raise ValueError("the projection is not a rotation and scale")
        return cls(scale, rotation, _FLIP * m[:, 3])

    def scaled(self, factor: float) -> Placement:
        """The same placement in a picture ``factor`` times as large."""
        return Placement(self.scale * factor, self.rotation, self.shift * factor)


def relative_pose(reference: Placement, frame: Placement, pivot: np.ndarray) -> np.ndarray:
    """(6,) rx, ry, rz, tx, ty, tz of ``frame`` relative to ``reference``: the rotation vector
    (degrees) of frame.rotation @ reference.rotation.T, the image-plane shift of ``pivot`` in face
    heights of the reference, and tz = VIEW_DISTANCE * (1 - reference.scale / frame.scale)."""
    shift = (frame.apply(pivot[None])[0] - reference.apply(pivot[None])[0]) / reference.scale
    depth = VIEW_DISTANCE * (1.0 - reference.scale / frame.scale)
    return np.concatenate([rotation_vector(frame.rotation @ reference.rotation.T), shift[:2], [depth]])


def frame_placement(reference: Placement, pose: np.ndarray, pivot: np.ndarray) -> Placement:
    """The placement that :func:`relative_pose` measured as ``pose`` (6,); its inverse up to the
    pivot's depth, which an orthographic picture does not show."""
    pose = np.asarray(pose, dtype=np.float64)
    turn, (tx, ty, tz) = rotation_from_vector(pose[:3]), pose[3:]
    scale = reference.scale / max(1.0 - tz / VIEW_DISTANCE, 0.05)
    rotation = turn @ reference.rotation
    at = reference.apply(pivot[None])[0] + reference.scale * np.array([tx, ty, 0.0])
    return Placement(scale, rotation, at - scale * rotation @ pivot)


def global_matrix(motion: np.ndarray, reference: Placement, size: tuple[int, int]) -> np.ndarray | None:
    """(2, 3) pixel map (x right, y down) from the reference picture to the frame for the global
    motion ``motion`` = (gx, gy, gs, gr): a similarity about the picture's centre of scale 1 + gs,
    turn gr degrees (counter-clockwise as seen), then a shift of (gx, gy) face heights of the
    reference (y up); None for no motion, so that a still camera leaves the picture bit-exact."""
    gx, gy, gs, gr = (float(v) for v in motion)
    if gx == gy == gs == gr == 0.0:
        return None
    angle = np.radians(gr)
    linear = (1.0 + gs) * np.array([[np.cos(angle), np.sin(angle)], [-np.sin(angle), np.cos(angle)]])
    centre = 0.5 * np.asarray(size, dtype=np.float64)
    shift = centre + reference.scale * np.array([gx, -gy]) - linear @ centre
    return np.column_stack([linear, shift])


def global_motion(matrix: np.ndarray, reference: Placement, size: tuple[int, int]) -> np.ndarray:
    """(4,) gx, gy, gs, gr of a (2, 3) similarity pixel map: :func:`global_matrix`'s inverse."""
    m = np.asarray(matrix, dtype=np.float64)
    scale = float(np.sqrt(max(np.linalg.det(m[:, :2]), 1e-12)))
    centre = 0.5 * np.asarray(size, dtype=np.float64)
    shift = m[:, :2] @ centre + m[:, 2] - centre
    return np.array([shift[0] / reference.scale, -shift[1] / reference.scale, scale - 1.0,
                     np.degrees(np.arctan2(m[0, 1], m[0, 0]))])


@dataclass(frozen=True)
class BodyRegion:
    """Where the body moves with its own shift: a weight by picture row (y down, the reference
    picture's pixels), 0 above ``chin``, 1 from ``chin + ramp`` down."""

    chin: float
    ramp: float

    @classmethod
    def of(cls, reference: Placement, vertices: np.ndarray) -> BodyRegion:
        """The body region below the face ``vertices`` (model space) as ``reference`` places them."""
        return cls(float(-reference.apply(vertices)[:, 1].min()), BODY_START * reference.scale)

    def weight(self, y: np.ndarray) -> np.ndarray:
        """How far points at rows ``y`` (any shape) move with the body: 0..1."""
        t = np.clip((np.asarray(y, dtype=np.float64) - self.chin) / self.ramp, 0.0, 1.0)
        return t * t * (3.0 - 2.0 * t)

    def moved(self, pixels: np.ndarray, shift: np.ndarray | None) -> np.ndarray:
        """(n, 2) reference-picture ``pixels`` moved by the body's ``shift`` (pixels; None: none)."""
        if shift is None:
            return pixels
        return pixels + self.weight(pixels[:, 1])[:, None] * shift


def body_shift(motion: np.ndarray, reference: Placement) -> np.ndarray | None:
    """(2,) pixels (x right, y down) of the body motion ``motion`` = (bx, by) face heights of the
    reference (y up); None for none, so that a still body leaves the picture bit-exact."""
    bx, by = (float(v) for v in motion)
    if bx == by == 0.0:
        return None
    return reference.scale * np.array([bx, -by])


def body_motion(shift: np.ndarray, reference: Placement) -> np.ndarray:
    """(2,) bx, by of a body ``shift`` in pixels: :func:`body_shift`'s inverse."""
    return np.array([shift[0], -shift[1]]) / reference.scale


def moved_body(picture: np.ndarray, still_picture: np.ndarray, zoom: tuple[float, float], body: BodyRegion,
               shift: np.ndarray) -> np.ndarray:
    """``still_picture`` (the reference ``picture`` at its size, ``zoom`` (x, y) times the picture's)
    with the body moved by ``shift`` (pixels of the picture) and the camera still: above the body
    it is as it was, where the body moves fully it is shifted (an affine warp), and only the rows of
    the ramp between are remapped (at 1920x1080 a whole-picture remap took 14 ms a frame)."""
    h, w = still_picture.shape[:2]
    zx, zy = zoom
    top = max(0, int(np.floor(zy * (body.chin + min(0.0, shift[1])))) - 2)
    full = min(h, max(top, int(np.ceil(zy * (body.chin + body.ramp + max(0.0, shift[1])))) + 2))
    out = still_picture.copy()
    if full < h:
        matrix = np.array([[zx, 0.0, zx * shift[0]], [0.0, zy, zy * shift[1] - full]])
        out[full:] = cv2.warpAffine(picture, matrix, (w, h - full), flags=cv2.INTER_LINEAR,
                                    borderMode=cv2.BORDER_REPLICATE)
    if top < full:
        maps = warp_map((w, h), zoom, body, (None, shift), rows=(top, full))
        out[top:full] = cv2.remap(picture, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out


def warp_map(size: tuple[int, int], zoom: tuple[float, float], body: BodyRegion,
             now: tuple[np.ndarray | None, np.ndarray | None],
             then: tuple[np.ndarray | None, np.ndarray | None] | None = None,
             rows: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """cv2.remap's (map x, map y), float32 (h, w) for ``size`` (w, h), pixels ``zoom`` (x, y) times
    the reference picture's: where each pixel of a frame whose (global motion map, body shift) is
    ``now`` comes from in the reference picture (``then`` None) or in a frame whose are ``then``
    (at the same zoom). A point q of the reference picture is at still(q + weight(q) * shift) in a
    frame; the inverse is taken with the weight where q's frame position lands, exact where the
    weight is flat, as it is everywhere but the ramp. Computed every BODY_GRID pixels and scaled up;
    ``rows`` (first, end): of those rows only."""
    w, (first, end) = size[0], rows or (0, size[1])
    h = end - first
    zx, zy = zoom
    # grid point i at pixel (i - 0.5) * BODY_GRID - 0.5: cv2.resize's own pixel centres, one point to
    # spare on each side, so that the pixels kept are interpolated, never clamped
    gw, gh = -(-w // BODY_GRID) + 2, -(-h // BODY_GRID) + 2
    gx, gy = np.meshgrid(((np.arange(gw) - 0.5) * BODY_GRID - 0.5) / zx,
                         (first + (np.arange(gh) - 0.5) * BODY_GRID - 0.5) / zy)
    points = np.column_stack([gx.ravel(), gy.ravel()])
    still, shift = now
    if still is not None:
        points = (points - still[:, 2]) @ np.linalg.inv(still[:, :2]).T
    if shift is not None:
        points = points - body.weight(points[:, 1])[:, None] * shift
    if then is not None:
        points = body.moved(points, then[1])
        if then[0] is not None:
            points = points @ then[0][:, :2].T + then[0][:, 2]
        points = points * [zx, zy]
    maps = cv2.resize(points.reshape(gh, gw, 2).astype(np.float32), (gw * BODY_GRID, gh * BODY_GRID),
                      interpolation=cv2.INTER_LINEAR)[BODY_GRID:BODY_GRID + h, BODY_GRID:BODY_GRID + w]
    return np.ascontiguousarray(maps[..., 0]), np.ascontiguousarray(maps[..., 1])


def face_texture(face: BaseFace) -> tuple[np.ndarray | None, np.ndarray]:
    """(texture or None, (n, 2) uv with v up) to draw the face alone: its own texture, else its
    reference picture where the picture's projection puts each vertex (enrolment leaves the texture
    out when it keeps the picture: the same frame)."""
    picture = face.picture
    if face.texture is not None or picture is None:
        return face.texture, face.uv
    height, width = picture.image.shape[:2]
    placed = Placement.from_matrix(picture.projection).apply(face.vertices)  # y up: minus the row
    return picture.image, np.column_stack([placed[:, 0] / width, 1.0 + placed[:, 1] / height])


def _padding(pixels: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Pixels to add left and top, right and bottom of a ``size`` picture so that ``pixels`` fall
    inside it with 2 to spare."""
    lo = np.maximum(np.ceil(-pixels.min(axis=0)), 0).astype(int) + 2
    hi = np.maximum(np.ceil(pixels.max(axis=0) - size), 0).astype(int) + 2
    return lo, hi


def outer_loop(faces: np.ndarray) -> np.ndarray:
    """(L,) vertex indices of the mesh's longest boundary loop (edges of one triangle only), in order."""
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    following: dict[int, list[int]] = {}
    for a, b in unique[counts == 1].tolist():
        following.setdefault(a, []).append(b)
        following.setdefault(b, []).append(a)
    best: list[int] = []
    seen: set[int] = set()
    for start in following:
        if start in seen:
            continue
        loop, previous, at = [start], -1, start
        while True:
            seen.add(at)
            nxt = next((n for n in following[at] if n != previous and n not in loop[1:]), None)
            if nxt is None or nxt == start:
                break
            loop.append(nxt)
            previous, at = at, nxt
        if len(loop) > len(best):
            best = loop
    return np.array(best, dtype=np.int64)


class SceneMesh:
    """The face mesh and its rings, in one vertex array: face vertices first, then ring after ring,
    then (with the person's open mouth) copies of the mouth opening's vertices.

    ``triangles``, ``uv`` (v up), ``texture`` (the reference picture, with the open mouth below
    it when there is one) and ``mouth_faces`` (the renderer's cavity and teeth, when there is
    not) are what the renderer takes; :meth:`positions` poses every vertex.
    """

    def __init__(self, face: BaseFace, picture: ReferencePicture, rings: tuple[float, ...] = RINGS) -> None:
        vertices, faces = np.asarray(face.vertices, dtype=np.float64), face.faces
        self.reference = reference = Placement.from_matrix(picture.projection)
        self.body = BodyRegion.of(reference, vertices)
        self.pivot = head_pivot(vertices)
        loop = outer_loop(faces)
        n, count = len(vertices), len(loop)
        rest = reference.apply(vertices)
        centre = reference.apply((0.5 * (vertices.min(axis=0) + vertices.max(axis=0)))[None])[0]
        edge = rest[loop]
        radii = np.asarray(rings, dtype=np.float64)
        ring_rest = np.concatenate([
            np.column_stack([centre[:2] + r * (edge[:, :2] - centre[:2]),
                             edge[:, 2] - (r - 1.0) * RING_DEPTH * reference.scale]) for r in radii])
        self._ring_model = (ring_rest - reference.shift) @ reference.rotation / reference.scale
        self._ring_rest = ring_rest
        self._rest, self._edge = vertices, np.tile(loop, len(radii))
        up = np.tile(np.clip((edge[:, 1] - centre[1]) / np.abs(edge[:, 1] - centre[1]).max(), 0.0, 1.0), len(radii))
        start = 1.0 + (HAIR_START - 1.0) * up  # above the eyes the hair turns with the head further out
        t = np.clip((np.repeat(radii, count) - start) / (radii[-1] - start), 0.0, 1.0)
        self._default = 1.0 - t * t * (3.0 - 2.0 * t)  # smoothstep: 1 .. 0
        learnt = picture.ring_weights
        use = learnt is not None and len(learnt) == len(self._default)
        self._weight = (np.asarray(learnt, dtype=np.float64) if use else self._default)[:, None]
        self.loop = loop
        index = np.concatenate([loop, n + np.arange(len(radii) * count)]).reshape(len(radii) + 1, count)
        inner, outer = index[:-1], index[1:]
        inner_next, outer_next = np.roll(inner, -1, axis=1), np.roll(outer, -1, axis=1)
        strips = np.concatenate([np.stack([inner, inner_next, outer_next], -1).reshape(-1, 3),
                                 np.stack([inner, outer_next, outer], -1).reshape(-1, 3)])
        pixels = (np.concatenate([rest, ring_rest]) * _FLIP)[:, :2]
        face_triangles, mouth = faces.copy(), face.mouth_faces
        self._mouth = np.zeros(0, np.int64)
        #: the person's open mouth as a mouth less open shows it (codec/render/mouth_interior.py), when drawn,
        #: and the texture's row where it starts (column 0)
        self.interior: MouthInterior | None = None
        self.mouth_row = 0
        self.picture_at = (0, 0)  # the texture's column and row of the picture's top left
        self._open = None  # (open mouth image, its vertices' pixels) when the scene draws the person's own
        height, width = picture.image.shape[:2]
        mouth_image, mouth_points = picture.mouth, picture.mouth_points
        # the picture's border in the texture, at most half its larger side each way (the texture's memory):
        # a ring vertex at rest past it takes the border's texel there (:meth:`textured`), where the
        # person's open mouth was left out and a flat cavity drawn instead (liveportrait_d3, pcavs_Pose_Source)
        most = max(width, height) // 2
        self._pad = lo, hi = tuple(np.minimum(side, most) for side in _padding(pixels, (width, height)))
        if mouth_image is not None and mouth_points is not None:
            self.picture_at = (int(lo[0]), int(lo[1]))
            self.mouth_row = height + int(lo[1] + hi[1]) + MOUTH_GAP
            self._mouth = mouth_vertices(face)
            copies = np.full(n, -1)
            copies[self._mouth] = len(pixels) + np.arange(len(self._mouth))
            face_triangles[mouth] = copies[faces[mouth]]
            self._open = (mouth_image, np.asarray(mouth_points, dtype=np.float64))
            loops = face.meta["loops"]
            self.interior = MouthInterior(mouth_image, self._open[1], self._mouth, loops["inner_lip_upper"],
                                          loops["inner_lip_lower"])
            mouth = np.zeros(len(faces), bool)
        self.rest_pixels = pixels  # of the face and ring vertices in the reference picture
        self.texture, self.uv = self.textured(picture.image)
        self.triangles = np.concatenate([face_triangles, strips]).astype(np.int32)
        self.mouth_faces = np.concatenate([mouth, np.zeros(len(strips), bool)])
        #: the mouth opening's triangles (indices into :attr:`triangles`) and the same on the face's own
        #: vertices, which the reference picture textures with its lips where they lie (:meth:`slivers`)
        self.opening = np.flatnonzero(face.mouth_faces)
        self.shut = faces[self.opening].astype(np.int32)

    def textured(self, image: np.ndarray, mouth: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(texture, (vertices, 2) uv with v up) that texture the scene by ``image``, a picture in the
        reference picture's place (the reference itself, or its eyes' lids drawn). With the person's open
        mouth (or ``mouth``, the same remapped: :attr:`interior`), it goes below the picture in one
        texture (at :attr:`mouth_row`), the picture's edges repeated as far as the rings reach, or half
        the picture's larger side (the clamp the picture alone would have; the picture's top left at
        :attr:`picture_at`)."""
        height, width = image.shape[:2]
        pixels = self.rest_pixels
        if self._open is None:
            return image, np.column_stack([pixels[:, 0] / width, 1.0 - pixels[:, 1] / height])
        lo, hi = self._pad
        padded = cv2.copyMakeBorder(image, lo[1], hi[1], lo[0], hi[0], cv2.BORDER_REPLICATE)
        mouth_image, mouth_points = self._open
        mouth_image = mouth_image if mouth is None else mouth
        below = self.mouth_row
        atlas = np.zeros((below + mouth_image.shape[0], max(padded.shape[1], mouth_image.shape[1]), 3), np.uint8)
        atlas[:padded.shape[0], :padded.shape[1]], atlas[below:, :mouth_image.shape[1]] = padded, mouth_image
        placed = np.concatenate([np.clip(pixels + lo, 1, [padded.shape[1] - 1, padded.shape[0] - 1]),
                                 mouth_points + [0.0, below]])
        height, width = atlas.shape[:2]
        return atlas, np.column_stack([placed[:, 0] / width, 1.0 - placed[:, 1] / height])

    def slivers(self, positions: np.ndarray) -> np.ndarray:
        """(opening,) bool: which of the mouth opening's triangles (:attr:`opening`) are slivers, less
        than SLIVER of the reference picture's pixels across among :meth:`positions`."""
        corners = positions[self.shut][..., :2]  # (k, 3, 2): the copies lie where the originals do
        sides = np.roll(corners, -1, axis=1) - corners
        area = np.abs(sides[:, 0, 0] * sides[:, 1, 1] - sides[:, 0, 1] * sides[:, 1, 0])
        return area < SLIVER * np.sqrt((sides ** 2).sum(axis=2).max(axis=1))

    def pixels(self, positions: np.ndarray) -> np.ndarray:
        """(n, 2) pixels (x right, y down) of the face and ring vertices among :meth:`positions`."""
        return (positions[:len(positions) - len(self._mouth)] * _FLIP)[:, :2]

    def default_weights(self) -> np.ndarray:
        """(rings x boundary,) how far each ring vertex follows the head without measured weights:
        a smoothstep from 1 at the face (1.3 above its centre, the hair) to 0 at the outermost ring."""
        return self._default.copy()

    def anchor_pixels(self, still: np.ndarray | None, shift: np.ndarray | None) -> np.ndarray:
        """(rings x boundary, 2) pixels (x right, y down) where the background under each ring vertex
        moves: by the body's ``shift`` (pixels; None: none) where it lies on the body, then by
        ``still`` (the frame's global motion, a (2, 3) pixel map; None: none)."""
        pixels = self.body.moved(self.ring_pixels(), shift)
        return pixels if still is None else pixels @ still[:, :2].T + still[:, 2]

    def ring_pixels(self, frame: Placement | None = None) -> np.ndarray:
        """(rings x boundary, 2) pixels (x right, y down) of the ring vertices at rest, or moving fully
        with a rigid head placed by ``frame``."""
        points = self._ring_rest if frame is None else frame.apply(self._ring_model)
        return (points * _FLIP)[:, :2]

    def positions(self, deformed: np.ndarray, frame: Placement, still: np.ndarray | None = None,
                  shift: np.ndarray | None = None) -> np.ndarray:
        """(vertices, 3) picture-axes positions: the deformed (pose-free) face placed by ``frame``;
        each ring vertex moved as its boundary vertex is (with the deformation: the neck stretches
        with an opening jaw instead of tearing from it), times the ring's weight, the rest of the
        way as the background past the outermost ring moves: by the body's ``shift`` (pixels, None:
        none) where it lies on the body (:attr:`body`), then by ``still`` (the frame's global motion,
        a (2, 3) pixel map; None: none)."""
        face = frame.apply(deformed)
        moved = self._ring_model + (deformed[self._edge] - self._rest[self._edge])
        anchor = self._ring_rest
        if still is not None or shift is not None:
            anchor = np.column_stack([self.anchor_pixels(still, shift) * _FLIP[:2], anchor[:, 2]])
        rings = anchor + self._weight * (frame.apply(moved) - anchor)
        return np.concatenate([face, rings, face[self._mouth]])
