"""The whole frame's motion against the reference picture: camera pan, zoom and roll, and the body's shift.

The receiver draws the still reference picture around the moving face; when
the camera moves, the background and the body move with it, and a picture held
still is wrong everywhere. Per frame, corners of the
reference picture outside the face are followed into the frame by pyramidal
Lucas-Kanade flow (starting from the last frame's motion, checked backwards),
and a similarity is fitted to them with RANSAC: four numbers per frame
(codec/render/picture.global_matrix), sent as GLOBAL_PARAMS. The body below the chin (shoulders,
torso) moves on its own when the person leans or shifts in the chair: corners there are followed
the same way, and what the camera's motion leaves of their shift is the body's (two numbers,
BODY_PARAMS, codec/render/picture.BodyRegion).

At enrolment, :class:`RingWeights` measures how far the picture around the
face (hair, neck, shoulders, the wall) follows the head, for the receiver's
rings.
"""


import cv2
import numpy as np

from facedeform.codec.model.face_model import BaseFace, ReferencePicture
from facedeform.codec.model.head_pose import image_to_face_axes
from facedeform.codec.render.picture import (
    BodyRegion,
    Placement,
    SceneMesh,
    body_motion,
    body_shift,
    global_matrix,
    global_motion,
)
from facedeform.sender.pose import STABLE_LANDMARKS, fit_pose

#: The face's landmark hull grown by this factor about its centre, and everything below the chin
#: (neck, shoulders, body, across the whole picture), is left out where the points start and where they
#: land: hair, ears and shoulders move with the person, not with the camera; corners there outnumber the
#: background's and would win the fit. (With only the band below the face left out, the bundled clip's
#: shoulders, wider than the band, gave 27 of its 35 corners: a still camera "moved" by up to 5 pixels
#: and 1.25 degrees with the speaker's body, and its whole picture lost 1.95 dB.)
FACE_GROW = 2.0
CORNERS = 300  # most points followed
#: Fewer agreeing points: keep the last frame's motion; a picture with fewer corners outside the
#: face (a plain wall) is not measured at all, and its stream carries no global motion. With 12,
#: the 17 corners of a plain blue wall and a shoulder gave motion up to 5 pixels that was not
#: there: 0.2 kbit/s more for 0.04 dB.
MIN_POINTS = 20
ROUND_TRIP = 0.5  # picture pixels: a point that does not flow back to where it started is dropped
RANSAC_PIXELS = 1.0
#: A fit that moves its agreeing points by less than this many picture pixels (median) is a still
#: camera (exactly). The motion is measured against the reference picture, so a slow pan is followed
#: once it has gone this far. (With "four fifths of the points move under a pixel" instead, the
#: bundled clip at 640x512, whose plain wall's corners are coding noise, half of them moving about a
#: pixel, sent a zoom and shift of up to 1.6 pixels in 38 of 75 frames.)
STILL_PIXELS = 2.0
#: Pictures whose larger side is this many pixels or more are followed at a whole fraction of their
#: size, at most this side (the thresholds above stay in the picture's pixels). At 1920x1080 the
#: flow, the sender's largest cost there, took 6.2 ms a frame at full size and 2.3 at half; the
#: bundled clip scaled to 1080p came out at 27.68 dB instead of 27.26 (worst frame 21.3, was 20.2).
WORK_SIDE = 960
#: Corners on the body (where it moves fully, codec/render/picture.BodyRegion) needed to measure it; a
#: picture with fewer (a plain shirt) carries no body motion, a frame with fewer keeps the last.
BODY_POINTS = 12
#: Most corners followed on the body: its shift is one mean, and following each costs the sender (the
#: bundled clip scaled to 1920x1080, one thread: 36 frames/s against 40 without the body; with 300 corners
#: and both guesses every frame, 28-32; followed one way, 38).
BODY_CORNERS = 100
#: A body shift (the mean of its agreeing points', picture pixels) is kept until it changes by this much,
#: and one smaller than this is none: the points' jitter on a still body would otherwise cost bits every frame.
BODY_STILL = 0.75
BODY_AGREE = 1.5  # picture pixels from the median within which a body point agrees
_IDENTITY = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def _flow(before: np.ndarray, after: np.ndarray, start: np.ndarray, guess: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(points, found) of pyramidal Lucas-Kanade from ``start`` in grey ``before`` to ``after``, from ``guess``."""
    found, ok, _ = cv2.calcOpticalFlowPyrLK(before, after, start, guess.copy(), None, None, (21, 21), 3,
                                            (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01),
                                            cv2.OPTFLOW_USE_INITIAL_FLOW)
    return np.asarray(found), np.asarray(ok).ravel() == 1


def face_mask(points: np.ndarray, size: tuple[int, int], grow: float = FACE_GROW, below: bool = True) -> np.ndarray:
    """(H, W) uint8: 255 outside the convex hull of (n, 2) pixel ``points`` grown ``grow`` times about
    its centre and, if ``below``, above the lowest point (y down: the chin)."""
    width, height = size
    centre = 0.5 * (points.min(axis=0) + points.max(axis=0))
    grown = centre + grow * (points - centre)
    mask = np.full((height, width), 255, np.uint8)
    cv2.fillConvexPoly(mask, cv2.convexHull(np.round(grown).astype(np.int32)), 0)
    if below:
        mask[max(0, int(np.ceil(points[:, 1].max()))):] = 0
    return mask


def _corners(gray: np.ndarray, mask: np.ndarray, most: int = CORNERS) -> np.ndarray:
    """(n, 1, 2) float32 corners of ``gray`` to follow (at most ``most``), where ``mask`` is set."""
    found = cv2.goodFeaturesToTrack(gray, most, 0.01, 5, mask=mask)
    return np.zeros((0, 1, 2), np.float32) if found is None else found.astype(np.float32)


class GlobalMotion:
    """Measures (gx, gy, gs, gr) of each frame against ``picture`` (where :attr:`usable`), then
    (bx, by), the body's shift (where :attr:`body`); ``vertices`` are the face model's, which the
    picture's projection places (to leave the face out of the reference's points)."""

    def __init__(self, picture: ReferencePicture, vertices: np.ndarray) -> None:
        self.reference = Placement.from_matrix(picture.projection)
        height, width = picture.image.shape[:2]
        self.size = (width, height)
        self._shrink = max(1, max(width, height) // WORK_SIDE)  # picture pixels a working pixel
        self._work = (round(width / self._shrink), round(height / self._shrink))
        self._gray = self._grey(cv2.cvtColor(picture.image, cv2.COLOR_RGB2GRAY))
        face = self.reference.apply(vertices)[:, :2] * [1.0, -1.0] / self._shrink
        self._points = _corners(self._gray, face_mask(face, self._work))
        self._matrix = _IDENTITY  # working pixels of the picture -> of the frame
        self._region = BodyRegion.of(self.reference, vertices)
        body = np.zeros(self._gray.shape, np.uint8)
        body[self._region.weight((np.arange(self._work[1]) + 0.5) * self._shrink) >= 1.0] = 255
        self._body_points = _corners(self._gray, body, BODY_CORNERS)
        self._shift = np.zeros(2)  # the body's, working pixels

    @property
    def usable(self) -> bool:
        """Whether the picture has corners enough outside the face to measure its motion on."""
        return len(self._points) >= MIN_POINTS

    @property
    def body(self) -> bool:
        """Whether the picture has corners enough on the body to measure the body's motion on."""
        return len(self._body_points) >= BODY_POINTS

    def measure(self, frame: np.ndarray, landmarks: np.ndarray | None) -> np.ndarray:
        """The global motion (4,) of BGR ``frame`` (scaled to the picture's size) whose tracked
        landmarks (pixels, None without a face) are given, where :attr:`usable`, then the body's (2,)
        where :attr:`body`; the last frame's when too few points agree."""
        gray = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        factor = self._work[0] / gray.shape[1]
        work = self._grey(gray)
        face = None if landmarks is None else np.asarray(landmarks)[:, :2] * factor
        if self.usable:
            self._follow(work, face)
        if self.body:
            self._follow_body(work, face)
        matrix = self._matrix.copy()
        matrix[:, 2] *= self._shrink  # in the picture's pixels
        return np.concatenate([global_motion(matrix, self.reference, self.size) if self.usable else [],
                               body_motion(self._shift * self._shrink, self.reference) if self.body else []])

    def _grey(self, gray: np.ndarray) -> np.ndarray:
        """``gray`` at the working size."""
        return gray if gray.shape[::-1] == self._work else cv2.resize(gray, self._work, interpolation=cv2.INTER_AREA)

    def _follow(self, gray: np.ndarray, face: np.ndarray | None) -> None:
        start = self._points
        guess = (start @ self._matrix[:, :2].T + self._matrix[:, 2]).astype(np.float32)
        found, ok = _flow(self._gray, gray, start, guess)
        back, ok_back = _flow(gray, self._gray, found, start)
        keep = ok & ok_back & (np.linalg.norm((back - start)[:, 0], axis=1) < ROUND_TRIP / self._shrink)
        if face is not None:
            width, height = self._work
            keep &= face_mask(face, self._work)[np.clip(np.round(found[:, 0, 1]).astype(int), 0, height - 1),
                                                 np.clip(np.round(found[:, 0, 0]).astype(int), 0, width - 1)] > 0
        if keep.sum() < MIN_POINTS:
            return
        matrix, inliers = cv2.estimateAffinePartial2D(start[keep], found[keep], method=cv2.RANSAC,
                                                      ransacReprojThreshold=RANSAC_PIXELS / self._shrink)
        if matrix is None or inliers is None or inliers.sum() < MIN_POINTS:
            return
        agree = start[keep][inliers.ravel() == 1, 0]
        moved = np.median(np.linalg.norm(agree @ matrix[:, :2].T + matrix[:, 2] - agree, axis=1))
        self._matrix = _IDENTITY if moved < STILL_PIXELS / self._shrink else matrix

    def _follow_body(self, gray: np.ndarray, face: np.ndarray | None) -> None:
        """The body's shift: where its corners went, less the camera's motion, as a shift before it.
        Followed from the last frame's shift, and where too few points agree on that, from none: a
        body that left the picture's edge and came back is found again."""
        visible = None if face is None else face_mask(face, self._work, 1.2, below=False)  # not where the head is
        for guess in (self._shift, np.zeros(2)) if self._shift.any() else (self._shift,):
            shifts = self._body_shifts(gray, visible, guess)
            if len(shifts) >= BODY_POINTS:
                middle = np.median(shifts, axis=0)
                agree = shifts[np.linalg.norm(shifts - middle, axis=1) < BODY_AGREE / self._shrink]
                if len(agree) >= BODY_POINTS:
                    self._settle(agree.mean(axis=0))
                    return

    def _settle(self, shift: np.ndarray) -> None:
        """Takes the measured ``shift`` (working pixels) as the body's, within BODY_STILL's dead zone."""
        if np.linalg.norm(shift) < BODY_STILL / self._shrink:
            self._shift = np.zeros(2)  # a still body exactly, as the camera's STILL_PIXELS
        elif np.linalg.norm(shift - self._shift) >= BODY_STILL / self._shrink:
            self._shift = shift

    def _body_shifts(self, gray: np.ndarray, visible: np.ndarray | None, shift: np.ndarray) -> np.ndarray:
        """(n, 2) shifts before the camera's motion of the body's corners that flow from where ``shift``
        would put them, where ``visible`` (a mask, None: everywhere) is set. One way only, unlike the
        camera's points: the shift is the mean of those near the median (_follow_body), which drops the
        strays a flow back would catch, and the flow back cost 1.7 ms a frame at 1920x1080 (the dev
        crops' mean PSNR the same within 0.01 dB at fd-send's defaults and at 4 kbit/s)."""
        start, linear, offset = self._body_points, self._matrix[:, :2], self._matrix[:, 2]
        found, keep = _flow(self._gray, gray, start, ((start + shift) @ linear.T + offset).astype(np.float32))
        if visible is not None:
            width, height = self._work
            keep &= visible[np.clip(np.round(found[:, 0, 1]).astype(int), 0, height - 1),
                            np.clip(np.round(found[:, 0, 0]).astype(int), 0, width - 1)] > 0
        return (found[keep, 0] - offset) @ np.linalg.inv(linear).T - start[keep, 0]


#: How much head motion (squared face heights, summed over frames) a ring vertex needs before its
#: own measured weight counts as much as the default fall-off (codec/render/picture.RINGS): about 100 frames
#: of a 0.04 face-height move. On the dev clips' 256x256 crops (mean PSNR, docs/picture.md): 0.05,
#: 0.15 and 0.3 within 0.02 dB of each other, 0.15 with the best 5th percentile.
WEIGHT_PRIOR = 0.15
#: Ring vertices each weight is averaged over along its ring: 1, 3, 5 gave 21.68, 21.73, 21.71 dB.
SPREAD = 3


class RingWeights:
    """How far each ring vertex of the face's scene mesh (codec/render/picture.SceneMesh) follows the head,
    measured frame by frame (:meth:`add`, so one pass over the enrolment clip serves this and the
    motion basis) and read by :meth:`weights`: for each vertex the least-squares factor, as the
    receiver draws it, between where the picture's content at the vertex went (Lucas-Kanade flow
    from the picture, checked backwards) and where a vertex moving fully with the head would go,
    each counted from where the background under it went (the camera's and the body's motion,
    :class:`GlobalMotion`), in 0..1, averaged along the ring weighted by the head motion seen and
    drawn toward the default fall-off where little was seen; the outermost ring stays put (0). Hair
    that swings with the head comes out near 1, a wall behind it and a shoulder near 0."""

    def __init__(self, face: BaseFace) -> None:
        picture = face.picture
        if picture is None:
            raise ValueError("ring weights need a face with a reference picture")
        self._scene = SceneMesh(face, picture)
        self._reference = cv2.cvtColor(picture.image, cv2.COLOR_RGB2GRAY)
        height, width = self._reference.shape
        self._rest = self._scene.ring_pixels()
        # a vertex past the picture's edge draws the edge (repeated): measure there
        self._probe = np.clip(self._rest, 4, [width - 5, height - 5]).astype(np.float32)
        self._vertices = np.asarray(face.vertices, dtype=np.float64)
        self._motion = GlobalMotion(picture, self._vertices)
        self._agree, self._seen = np.zeros(len(self._rest)), np.zeros(len(self._rest))

    def add(self, frame: np.ndarray, landmarks: np.ndarray | None) -> None:
        """One BGR ``frame`` of the picture's size and its tracked landmarks (pixels; None without a face)."""
        motion = self._motion.measure(frame, landmarks)
        if landmarks is None:
            return
        stable = list(STABLE_LANDMARKS)
        placement = fit_pose(image_to_face_axes(landmarks)[stable], self._vertices[stable]).placement()
        background = self._background(motion) - self._rest
        head = self._scene.ring_pixels(placement) - self._rest - background
        gray = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        start = self._probe[:, None].copy()
        guess = (self._probe + background + 0.5 * head)[:, None].astype(np.float32)
        found, ok = _flow(self._reference, gray, start, guess)
        back, ok_back = _flow(gray, self._reference, found, start)
        good = ok & ok_back & (np.linalg.norm((back - start)[:, 0], axis=1) < 2 * ROUND_TRIP)
        self._agree += np.where(good, (((found - start)[:, 0] - background) * head).sum(axis=1), 0.0)
        self._seen += np.where(good, (head * head).sum(axis=1), 0.0)

    def _background(self, motion: np.ndarray) -> np.ndarray:
        """(rings x boundary, 2) pixels where the background under each ring vertex went by ``motion``
        (:meth:`GlobalMotion.measure`'s)."""
        reference, size, parts = self._motion.reference, self._motion.size, list(motion)
        still = global_matrix(np.array(parts[:4]), reference, size) if self._motion.usable else None
        shift = body_shift(np.array(parts[-2:]), reference) if self._motion.body else None
        return self._scene.anchor_pixels(still, shift)

    def weights(self) -> np.ndarray:
        """(rings x boundary,) the weights of the frames added so far."""
        scene, count = self._scene, len(self._scene.loop)
        agree, seen = _around(self._agree.reshape(-1, count)), _around(self._seen.reshape(-1, count))
        weight = np.clip(agree / np.maximum(seen, 1e-12), 0.0, 1.0)
        confidence = seen / (seen + WEIGHT_PRIOR * scene.reference.scale ** 2)
        out = confidence * weight + (1.0 - confidence) * scene.default_weights().reshape(-1, count)
        out[-1] = 0.0
        return out.ravel()


def _around(values: np.ndarray) -> np.ndarray:
    """(rings, n) sums over SPREAD neighbours along each (closed) ring."""
    return np.sum([np.roll(values, shift, axis=1) for shift in range(-(SPREAD // 2), SPREAD // 2 + 1)], axis=0)
