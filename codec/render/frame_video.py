"""The picture layer: the real frame, scaled down, as a video coded by VP9 from the model's picture
(libvpx, codec/render/vp9.py), drawn with the model's picture block by block.

Why a video codec of the frame itself, not a residual over the model's picture: on the moving
dev clips' 256x256 crops, an earlier layer that coded what the model missed as WebP residuals
(every still image on its own) gave pcavs_Pose_Source 23.4 dB at 4 kbit/s and 25.1 at 10; AV1 of
the model's residual as a video did worse than AV1 of the frame (the residual's edges move where
the model is off, which costs more than the frame), and AV1 of the frame at 64x64 gave 26.1 dB at
7.9 kbit/s: its motion search follows a turning head and a leaning body that the model cannot.
Why VP9 and not AV1 (SVT-AV1, until stream version 17): both ends hold the model's picture of every
frame, and libvpx takes a picture of the caller's into a reference slot, so each video frame is
predicted from the model's picture as well as from the last video frame (:class:`VideoEncoder`):
the model's detail costs nothing where it is right, and a call's first key costs what the model
misses instead of a picture. The model also keeps what a picture that small cannot show: where the
sender finds the model's picture nearer the frame (a still face's detail, most of a still clip),
that block is the model's, moved by a pixel or two onto where the video shows it; elsewhere the
video's, sharpened by the model's detail where the two agree (:func:`blend`). The numbers are in
docs/picture_layer.md.

A layer packet's payload (the picture packet of protocol/framing.py)::

    flags (1 byte: bit 0 key, bit 1 blocks only, bit 2 the model's blocks not moved, bits 3-7 a counter mod 32)
    | the model's blocks (arithmetic code) | a VP9 frame (a key: the grey key frame's length, 2 bytes,
      the grey key frame, the frame)

Between video frames the last one is held, carried by the model's motion (the view's ``carry``,
given to :meth:`VideoLayer.draw`). A payload of blocks only (no video) lets the sender hand a
block back to the model between video frames, when the carried frame no longer matches what moved.

The blocks are coded as changes from the last packet's (from none at a key, where a receiver can
start). Both ends run the same :class:`VideoLayer` on the same payloads, so they draw the same
pixels; a receiver that missed a packet (the counter jumps), or the parameters of a payload's frame
(its model's picture is then not the sender's), draws the model's picture alone until the next key.
"""

import os
from collections import deque
from collections.abc import Callable
from fractions import Fraction
from functools import lru_cache
from typing import cast

import cv2
import numpy as np
from numba import njit

from facedeform.codec.render import vp9
from facedeform.common.scheduling import kept_scheduling
from facedeform.protocol.arith import AdaptiveBit, decode_run, encode_run

BLOCK = 32  # pixels of the picture per model-or-video choice (16: four to seven times the bits for 0.24 dB)
#: Where the model's blocks meet the video's, the seam's blur grows with the picture's side over the
#: video's, up to this many times half a block: where the video is a half of the picture's side
#: (256x256 at 4 and 10 kbit/s) a model block misplaced by a few pixels meets the video's blur in a
#: double edge. Twice raised the nine dev crops' PSNR at 4 kbit/s by 0.01-0.14 dB (0.075 on average,
#: every clip), at 10 by 0.02 on average (-0.04 to +0.06); at 30 kbit/s, a video of the picture's
#: size, blurred as much it lost 0.015 on average (pcavs_Pose_Source 0.13), so it keeps half a block
#: there (docs/picture_layer.md). Half as much lost 0.09 dB at 4 kbit/s.
SEAM = 2.0
#: SVT-AV1's preset for a still picture. On one 256x256 face's picture at CRF 25 (PyAV's conversion),
#: preset 2 took 2 % fewer bytes than 4 and gave 0.2 dB more, in 0.25 s against 0.1 (not tried at
#: 1920x1080, where enrolment would wait for it); preset 6 took a quarter more bytes.
STILL_PRESET = "4"
_TEMPORAL_DELIMITER = b"\x12\x00"  # every temporal unit's first OBU: dropped on the wire
_CHANGE = (20, 1)  # starting counts of a block's change: most blocks keep their choice
#: A payload's flags: a key, blocks only, the model's blocks drawn where the model is (not moved onto the
#: video), and a counter in the bits above (COUNTER values) by which a receiver knows it missed one.
KEY, BLOCKS_ONLY, STILL, COUNTER = 1, 2, 4, 32
#: Frames the video codes after a key or a dropped frame before it may drop one again. libvpx learns its
#: frames' sizes only from those it keeps, and after a drop codes the next at its coarsest: dropping
#: at once again, it went on dropping every other frame (sadtalker_RD_Radio34's crop at 4 kbit/s, 28
#: of 57, from the call's first key on, whose frame had emptied its buffer).
CALM = 2
SMALLEST_SIDE = 64  # pixels: the smallest video the layer codes
HELD = 64  # payloads held for frames not yet drawn: more than a receiver's buffer holds


def video_size(picture_size: tuple[int, int], side: float) -> tuple[int, int]:
    """The video's (w, h) for a picture of ``picture_size`` whose larger side becomes ``side``
    pixels: multiples of 8 (libvpx takes a reference only of its frames' size rounded up to 8), at
    least SMALLEST_SIDE, at most the picture's (rounded down to 8) where it is larger."""
    scale = min(1.0, max(side / max(picture_size), SMALLEST_SIDE / min(picture_size)))
    w, h = (max(SMALLEST_SIDE, min(8 * (n // 8), 8 * round(n * scale / 8))) for n in picture_size)
    return w, h


class VideoEncoder:
    """The layer's video: VP9 in real time (codec/render/vp9.py) at ``bitrate`` bit/s over frames ``fps`` a
    second (the rate libvpx's own control aims at), each frame coded from the last one and from the
    model's picture of its own frame, which both ends draw (:meth:`encode`)."""

    def __init__(self, size: tuple[int, int], bitrate: float, fps: float) -> None:
        self._vp9 = vp9.Encoder(size, bitrate, fps)
        self.size = size
        self._kept = 0  # frames coded since the last key or drop

    def encode(self, rgb: np.ndarray, model: np.ndarray, key: bool = False) -> bytes:
        """The coded frame of ``rgb`` ((h, w, 3) uint8 at the video's size), ``model`` (the same size:
        the model's picture of the frame, :meth:`receiver.face_view.PictureView.reference_picture`) in
        its golden reference. A key is a flat grey key frame (a dozen bytes: VP9 starts from a key) with
        every reference then set to ``model``, and the frame coded from them, behind the key's length
        (2 bytes): a call's first frame costs what the model misses, not a picture. b"": a frame that
        would have overrun libvpx's buffer, dropped (never a key)."""
        planes, reference = to_yuv(rgb), to_yuv(model)
        if not key:
            self._vp9.set_reference(vp9.GOLDEN, reference)
            video = self._vp9.encode(planes, keep_golden=True, droppable=self._kept >= CALM)
            self._kept = self._kept + 1 if video else 0
            return video
        self._kept = 0
        grey = self._vp9.encode(np.full_like(planes, 128), key=True)
        for slot in vp9.SLOTS:
            self._vp9.set_reference(slot, reference)
        # the frame after a key refreshes the golden slot, as libvpx plans it to: kept there, the model's
        # picture cost tpsmm_driving's crop 1.0 dB at 4 kbit/s and liveportrait_d11 0.4 (cause not traced)
        return len(grey).to_bytes(2, "big") + grey + self._vp9.encode(planes)

    def close(self) -> None:
        """Ends the encoder, once."""
        self._vp9.close()


class VideoDecoder:
    """What :class:`VideoEncoder` codes from a key on, decoded as it was coded: each frame with the
    model's picture of it in the golden reference (in every reference at the key), frames of at most
    ``largest`` (w, h)."""

    def __init__(self, largest: tuple[int, int]) -> None:
        self._vp9 = vp9.Decoder(largest)

    def decode(self, video: bytes, key: bool, model: Callable[[tuple[int, int]], np.ndarray]) -> np.ndarray | None:
        """The (h, w, 3) RGB frame of ``video`` (:meth:`VideoEncoder.encode`), ``model(the video's size)``
        giving the model's picture it was coded from; None if it does not decode (or no key came)."""
        if key:
            length = int.from_bytes(video[:2], "big")
            if len(video) < 2 + length or self._vp9.decode(video[2:2 + length]) is None:
                return None
            video = video[2 + length:]
        size = self._vp9.size
        if size is None:
            return None
        picture = to_yuv(model(size))
        if not all(self._vp9.set_reference(slot, picture) for slot in (vp9.SLOTS if key else (vp9.GOLDEN,))):
            return None
        planes = self._vp9.decode(video)
        return None if planes is None else from_yuv(planes, size)


def to_yuv(rgb: np.ndarray) -> np.ndarray:
    """(h, w, 3) uint8 RGB of even sides as its I420 planes, (3h/2, w) uint8, as a still picture is
    coded (:func:`encode_still`): full-range BT.601 (JPEG's YCbCr, rounded), the chroma the mean of
    each 2x2 pixels.

    Why not PyAV's own conversion (libswscale's), which the layer's video keeps: it truncates where
    this rounds, both ways, which drew every decoded colour 1.0-1.3 levels dark, and it kept less of
    the colour: the nine dev clips' 256x256 reference pictures as AV1 at CRF 25 came out 1.4-2.7 dB
    below this conversion's, which spends 10-14 % more bytes there; at CRF 28, 3-4 % fewer bytes than
    libswscale's at 25, this one is still 0.5-2.0 dB above (docs/face_file.md). For the layer's video
    it moved the whole picture by +0.03 dB on average at 4 kbit/s and +0.05 at 10, clip by clip
    -0.23 to +0.20, and would have needed a new stream version (docs/picture_layer.md)."""
    height, width = rgb.shape[:2]
    ycc = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2YCrCb)
    chroma = cv2.resize(ycc[:, :, 1:], (width // 2, height // 2), interpolation=cv2.INTER_AREA)
    return np.concatenate([ycc[:, :, 0].ravel(), chroma[:, :, 1].ravel(), chroma[:, :, 0].ravel()]).reshape(
        height * 3 // 2, width)


def from_yuv(planes: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The (h, w, 3) uint8 RGB of :func:`to_yuv`'s ``planes`` of a picture of ``size`` (w, h), the chroma
    scaled up bilinearly."""
    width, height = size
    quarter = (width // 2) * (height // 2)
    chroma = planes[height:].reshape(-1)
    blue, red = (chroma[i * quarter:(i + 1) * quarter].reshape(height // 2, width // 2) for i in (0, 1))
    full = cv2.resize(np.dstack([red, blue]), (width, height), interpolation=cv2.INTER_LINEAR)
    return cv2.cvtColor(np.dstack([planes[:height], full]), cv2.COLOR_YCrCb2RGB)


def even(size: tuple[int, int]) -> tuple[int, int]:
    """``size`` (w, h) with each side rounded up to even, as 4:2:0 needs."""
    return size[0] + size[0] % 2, size[1] + size[1] % 2


def encode_still(rgb: np.ndarray, crf: int) -> bytes:
    """``rgb`` ((h, w, 3) uint8) as one AV1 key frame at SVT-AV1's ``crf`` (0-63, finer lower), a
    temporal unit without its temporal delimiter as :meth:`VideoEncoder.encode` gives: a face file's
    pictures (codec/face_file/format.py), read back by :class:`StillDecoder`. An odd side is coded
    one pixel longer, its last row or column repeated (:func:`even`)."""
    import av

    os.environ.setdefault("SVT_LOG", "1")
    height, width = rgb.shape[:2]
    padded = cv2.copyMakeBorder(rgb, 0, height % 2, 0, width % 2, cv2.BORDER_REPLICATE)
    codec = av.CodecContext.create("libsvtav1", "w")
    codec.width, codec.height = even((width, height))
    codec.pix_fmt, codec.time_base = "yuv420p", Fraction(1, 25)
    codec.options = {"preset": STILL_PRESET, "crf": str(crf)}
    with kept_scheduling():
        codec.open()
    frame = av.VideoFrame.from_ndarray(to_yuv(padded), format="yuv420p")
    frame.pts = 0
    return _undelimited(b"".join(bytes(p) for p in [*codec.encode(frame), *codec.encode(None)]))


def _undelimited(data: bytes) -> bytes:
    """A temporal unit without its temporal delimiter, as it goes on the wire."""
    return data[len(_TEMPORAL_DELIMITER):] if data.startswith(_TEMPORAL_DELIMITER) else data


class StillDecoder:
    """dav1d, one frame in, one out, refusing a frame of more pixels than ``largest`` (w, h) before
    it is allocated, and one wider or taller after."""

    def __init__(self, largest: tuple[int, int]) -> None:
        import av

        self._codec = cast("av.VideoCodecContext", av.CodecContext.create("libdav1d", "r"))
        self._codec.options = {"max_frame_delay": "1", "max_pixels": str(largest[0] * largest[1])}
        self.largest = largest

    def decode_still(self, data: bytes) -> np.ndarray | None:
        """The (h, w, 3) uint8 RGB picture of :func:`encode_still`'s bytes; None unless they decode
        to one 8-bit 4:2:0 frame of even sides within ``largest``."""
        frame = self._frame(data)
        if frame is None or frame.format.name != "yuv420p" or (frame.width, frame.height) != even(
                (frame.width, frame.height)):
            return None
        return from_yuv(frame.to_ndarray(format="yuv420p"), (frame.width, frame.height))

    def _frame(self, data: bytes):
        import av

        try:
            frames = self._codec.decode(av.Packet(_TEMPORAL_DELIMITER + data))
        except (av.error.FFmpegError, ValueError):
            return None
        if len(frames) != 1 or frames[0].width > self.largest[0] or frames[0].height > self.largest[1]:
            return None
        return frames[0]


def shrunk(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``image`` scaled down to ``size`` by area averaging: halved while it stays at least twice
    ``size`` (OpenCV's halving is its fast way: from 1920x1080, 0.9 ms on one thread to 960x540, then
    1.0 to the video's 480x272, against 3.0-5 in one step; the halves round twice, to within a level of
    the one step's mean), then scaled the rest of the way."""
    while image.shape[1] >= 2 * size[0] and image.shape[0] >= 2 * size[1] and \
            image.shape[1] % 2 == 0 and image.shape[0] % 2 == 0:
        image = cv2.resize(image, (image.shape[1] // 2, image.shape[0] // 2), interpolation=cv2.INTER_AREA)
    same = image.shape[1::-1] == tuple(size)
    return image if same else cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def drawn_size(picture_size: tuple[int, int], video: tuple[int, int]) -> tuple[int, int]:
    """(w, h) at which both ends draw the model's picture that a ``video``-sized frame of the layer is
    coded from (then :func:`shrunk` to it): the picture's own, halved while its larger side stays at
    least twice the video's. Drawn at the video's size, its texture is read a pixel in two (0.07 dB
    at 4 kbit/s on the dev crops against 0.41 at twice); at 1920x1080 with a 480x272 video the whole
    size cost each end 20 ms a video frame, 960x540 is what the sender chooses the blocks at anyway."""
    w, h = picture_size
    while w % 2 == 0 and h % 2 == 0 and max(w, h) // 2 >= 2 * max(video):
        w, h = w // 2, h // 2
    return w, h


def blocks_of(picture_size: tuple[int, int]) -> tuple[int, int]:
    """(rows, columns) of BLOCK-pixel blocks over a picture of ``picture_size`` (w, h)."""
    w, h = picture_size
    return -(-h // BLOCK), -(-w // BLOCK)


def blocks_in(box: tuple[float, float, float, float], picture_size: tuple[int, int]) -> np.ndarray:
    """(rows, columns) bool: the blocks that ``box`` (x0, y0, x1, y1 in the picture's pixels) overlaps."""
    rows, columns = blocks_of(picture_size)
    x0, y0, x1, y1 = box
    top, left = np.arange(rows)[:, None] * BLOCK, np.arange(columns)[None, :] * BLOCK
    return (top + BLOCK > y0) & (top < y1) & (left + BLOCK > x0) & (left < x1)


def encode_blocks(before: np.ndarray, after: np.ndarray) -> bytes:
    """The (rows, columns) bool choice ``after`` as changes from ``before``."""
    return encode_run((before != after).ravel(), AdaptiveBit(*_CHANGE))


def decode_blocks(before: np.ndarray, data: bytes) -> tuple[np.ndarray, int] | None:
    """(the choice, bytes it took) from the start of ``data``; None if it ends too soon."""
    decoded = decode_run(data, before.size, AdaptiveBit(*_CHANGE))
    if decoded is None:
        return None
    changed, used = decoded
    return before ^ changed.astype(bool).reshape(before.shape), used


#: (the model's picture as its blocks draw it; the video scaled up to the model's picture; (H, W, 3)
#: int16 the model's detail (its picture less its picture at the video's size); (H, W) float32 how far
#: the two agree: 1 where the detail is added). Where the flow is made (ALIGNED), the detail is moved
#: onto the video, and the picture too unless a payload says it stays (STILL, :func:`choose_payload`).
VideoParts = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
#: Pictures of at most this many pixels have the model's detail moved onto the video by optical flow
#: (:func:`_alignment`). Larger ones add it where it is: the flow would cost more there than it is
#: known to give (not measured above 256x256 crops), and a picture that large gets a video large
#: enough to show most of the detail itself.
ALIGNED = 720 * 576
#: The flow is found at the video's size, at most this many pixels on its larger side: the model's
#: picture is off from the video by a few of the video's pixels (a fold, the jaw, a turned head), and
#: a coarser flow is smoother (DIS optical flow, OpenCV's medium preset; 1.0 ms at 128x128).
FLOW_SIDE = 128
FLOW_BLUR = 1.0  # the flow's Gaussian blur, in its own pixels: one fold of the model, one flow
MOST_SHIFT = 8.0  # the flow's pixels: a larger shift is a wrong match, not the model's error
#: The flow's pixels the model's picture moves at most in its own blocks. The model is there because
#: its detail is right; moved by the flow, it sits where the video shows the head (a turned head,
#: a jaw line a pixel or two off) instead of drawing it twice against the video's blocks around.
#: Nine dev crops at 4, 6, 8 and 10 kbit/s against the model as it is: +0.02, +0.20, +0.25 and
#: +0.22 dB, VMAF +3.1, +4.4, +4.2 and +3.7; moved as far as the detail (8 px) +0.21 dB at 10
#: kbit/s but -0.15 at 4 with the 5th percentile -0.45, the still faces' detail moved by the
#: flow's noise; a choice per block between moved and not, coded beside the blocks, gained less
#: (docs/picture_layer.md).
MODEL_SHIFT = 2.0
#: Within this many of the flow's pixels of the picture's border the model's move fades to none: DIS has
#: nothing beyond the border to match, and in a flat background its noise moved the model's border rows
#: (the bundled clip at 10 kbit/s: its dark top line smeared down, 30.6 dB against 33.1 unmoved).
EDGE = 8
#: How far the video and the model's coarse picture agree: most - apart / scale within 0..1 (apart:
#: their mean absolute difference over the channels, blurred). Where the detail was moved onto the
#: video, what is left apart is the video's blur and its coding, so the detail holds further (AGREE);
#: unmoved, a difference is as likely a misplaced edge, where added detail draws a double one.
AGREE, UNMOVED_AGREE = (2.0, 32.0), (1.5, 8.0)


def blend(parts: VideoParts, chosen: np.ndarray, picture_size: tuple[int, int],
          video_size: tuple[int, int] | None = None) -> np.ndarray:
    """The picture drawn (``parts``: :func:`video_parts` of the video frame, of ``video_size``, None: the
    picture's, over the model's picture): the model's picture moved onto the video in the blocks
    ``chosen`` (True, or a weight from 0 to 1, of a picture of ``picture_size``), elsewhere the video
    frame with the model's detail added where its coarse picture agrees with the video's; the two meet
    softly over half a block, more where a video pixel covers more of the picture's (SEAM)."""
    model, up, detail, agree = parts
    out = np.empty_like(model)
    wider = 1.0 if video_size is None else min(SEAM, max(1.0, picture_size[0] / video_size[0]))
    _mix(model, up, detail, agree, _soft(chosen, picture_size, model.shape[1::-1], wider), out)
    return out


def _soft(chosen: np.ndarray, picture_size: tuple[int, int], size: tuple[int, int], wider: float = 1.0
          ) -> np.ndarray:
    """(h, w) float32 weight of the model's picture at ``size``: the blocks ``chosen`` blurred over
    ``wider`` times half a block (at a quarter of the picture's scale, where it costs a sixteenth)."""
    quarter = BLOCK // 4
    pw, ph = picture_size
    mask = np.kron(chosen, np.ones((quarter, quarter))).astype(np.float32)[:-(-ph // 4), :-(-pw // 4)]
    return cv2.resize(cv2.GaussianBlur(mask, (0, 0), wider * quarter / 4), size, interpolation=cv2.INTER_LINEAR)


def video_parts(model: np.ndarray, video: np.ndarray, move: bool = True,
                small: np.ndarray | None = None) -> VideoParts:
    """What :func:`blend` and :func:`choose_payload` draw the video frame ``video`` (any size; carried by
    the face to ``model``'s frame, where it was another's) with, over ``model`` ((H, W, 3) uint8): the
    model's picture moved onto the video (MODEL_SHIFT; as it is if not ``move``), the video scaled up,
    the model's detail, and where the two agree. Made once a frame, by both ends alike. ``small``:
    ``model`` :func:`shrunk` to the video's size where the caller has it (the reference a video frame
    was decoded from: at 1920x1080 a shrinking of 3-5 ms saved).

    The detail is what the video is too small to show: the model's picture less itself at the video's
    size. Added where it is, it lands a few pixels off wherever the model's picture is (the lips, the
    jaw line, a turned head), and draws a double edge; so on pictures up to ALIGNED it is first moved
    to where the video shows it, by the optical flow from the video to the model's coarse picture.
    On the nine dev crops at 4 kbit/s that gave +0.08 dB (-0.13 to +0.30), SSIM +0.001 and VMAF
    +1.3 on average, at 10 kbit/s +0.19 dB, SSIM +0.005 and VMAF +4.0, every clip up
    (docs/picture_layer.md). Where the two agree is measured at the video's size, where both are as
    sharp as they are, and scaled up: at 1920x1080 the parts took 8.4 ms measured at the picture's,
    5.9 this way."""
    h, w = model.shape[:2]
    size = video.shape[1::-1]
    up_small = np.ascontiguousarray(video)
    up = cv2.resize(up_small, (w, h), interpolation=cv2.INTER_LINEAR)
    model = np.ascontiguousarray(model)
    model_small = shrunk(model, size) if small is None or small.shape[1::-1] != size else small
    detail = cv2.subtract(model, cv2.resize(model_small, (w, h), interpolation=cv2.INTER_LINEAR), dtype=cv2.CV_16S)
    most, scale = UNMOVED_AGREE
    if w * h <= ALIGNED and size != (w, h):  # a video of the picture's size leaves no detail to move
        flow = _alignment(up_small, model_small)
        detail, model_small = _moved(detail, flow), _moved(model_small, flow)
        if move:
            model = _moved(model, _bounded(flow, MODEL_SHIFT) * _edge_fade(*flow.shape[:2]))
        most, scale = AGREE
    agree = _agreement(cv2.GaussianBlur(_apart(up_small, model_small), (0, 0), 1.0), most, scale)
    return model, up, detail, cv2.resize(agree, (w, h), interpolation=cv2.INTER_LINEAR)


def _alignment(video: np.ndarray, model: np.ndarray) -> np.ndarray:
    """(h, w, 2) float32, at most FLOW_SIDE on the larger side: for each pixel of ``video`` ((H, W, 3)
    uint8), how far off (x, y, in the flow's pixels) ``model``'s picture (the same size) shows it."""
    h, w = video.shape[:2]
    scale = min(1.0, FLOW_SIDE / max(w, h))
    size = (max(8, round(w * scale)), max(8, round(h * scale)))
    grey = [cv2.cvtColor(shrunk(np.ascontiguousarray(image), size), cv2.COLOR_RGB2GRAY) for image in (video, model)]
    dis = cv2.DISOpticalFlow.create(cv2.DISOpticalFlow_PRESET_MEDIUM)
    flow = dis.calc(grey[0], grey[1], None)  # type: ignore[call-overload]  # None: no flow to start from
    return _bounded(cv2.GaussianBlur(flow, (0, 0), FLOW_BLUR), MOST_SHIFT)


def _bounded(flow: np.ndarray, most: float) -> np.ndarray:
    """``flow`` ((h, w, 2) float32) with every vector longer than ``most`` shortened to it."""
    length = np.sqrt((flow * flow).sum(axis=2, keepdims=True))
    return flow * np.minimum(1.0, most / np.maximum(length, 1e-6)).astype(np.float32)


def _moved(image: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """``image`` ((H, W, C), uint8 or int16) with each pixel taken from where ``flow`` (any size, its
    own pixels) points, the flow scaled to the image's size; beyond the edge the edge's pixels."""
    h, w = image.shape[:2]
    fh, fw = flow.shape[:2]
    shift = cv2.resize(flow * np.array([w / fw, h / fh], np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
    xs, ys = _grid(w, h)
    return cv2.remap(image, xs + shift[:, :, 0], ys + shift[:, :, 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


@lru_cache(maxsize=8)
def _edge_fade(h: int, w: int) -> np.ndarray:
    """(h, w, 1) float32: 0 at the border, rising to 1 at EDGE pixels in (see EDGE)."""
    xs, ys = _grid(w, h)
    inside = np.minimum(np.minimum(xs, w - 1 - xs), np.minimum(ys, h - 1 - ys))
    return np.minimum(1.0, inside / EDGE)[:, :, None].astype(np.float32)


@lru_cache(maxsize=8)
def _grid(w: int, h: int) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) float32 (h, w) each: every pixel's own place, for cv2.remap."""
    ys, xs = np.mgrid[:h, :w].astype(np.float32)
    return xs, ys


@njit(cache=True)
def _apart(a: np.ndarray, b: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """(H, W) float32 mean over the channels of |a - b| ((H, W, 3) uint8 each, C-contiguous), over
    the arrays seen flat (see _mix)."""
    h, w = a.shape[:2]
    flat_a, flat_b = a.reshape(-1), b.reshape(-1)
    out = np.empty(h * w, np.float32)
    for i in range(h * w):
        total = np.int32(0)
        for c in range(3):
            total += abs(np.int32(flat_a[3 * i + c]) - np.int32(flat_b[3 * i + c]))
        out[i] = np.float32(total) / np.float32(3.0)
    return out.reshape(h, w)


@njit(cache=True)
def _agreement(apart: np.ndarray, most: float, scale: float) -> np.ndarray:  # pragma: no cover - compiled
    """``apart`` ((H, W) float32, overwritten) as how far the video and the model's coarse picture
    agree: most - apart / scale within 0..1, the float32 NumPy computes, in one pass instead of three
    (3.6 ms at 1080p, this under 1)."""
    high, step, top = np.float32(most), np.float32(scale), np.float32(1.0)
    flat = apart.reshape(-1)
    for i in range(flat.size):
        flat[i] = min(max(high - flat[i] / step, np.float32(0.0)), top)
    return apart


@njit(cache=True)
def _mix(model, up, detail, agree, soft, out) -> None:  # pragma: no cover - compiled
    """out = soft * model + (1 - soft) * (up + agree * detail), rounded into 0-255 (the
    model's pixel exactly where soft is 1), in float32 over the arrays seen flat (C-contiguous), in
    a loop without branches, which vectorises: at 1080p 2 ms. (Indexed as (y, x, c), with float64
    sums, a shortcut where soft is 1 and a float to uint8 conversion, it took 10-11 ms.)"""
    one, half, top = np.float32(1.0), np.float32(0.5), np.float32(255.0)
    flat_model, flat_up, flat_detail = model.reshape(-1), up.reshape(-1), detail.reshape(-1)
    flat_agree, flat_soft, flat_out = agree.reshape(-1), soft.reshape(-1), out.reshape(-1)
    for i in range(flat_soft.size):
        s, a = flat_soft[i], flat_agree[i]
        for c in range(3):
            m = np.float32(flat_model[3 * i + c])
            sharpened = np.float32(flat_up[3 * i + c]) + a * np.float32(flat_detail[3 * i + c])
            v = s * m + (one - s) * sharpened + half
            flat_out[3 * i + c] = np.uint8(np.int32(min(max(v, np.float32(0.0)), top)))


def choose_payload(parts: VideoParts, still: np.ndarray, frame: np.ndarray, before: np.ndarray,
                   hysteresis: float = 1.5, favour: np.ndarray | None = None, shrink: int = 1
                   ) -> tuple[np.ndarray, bool]:
    """The sender's choice, what a payload says: (the blocks where the model's picture is nearer
    ``frame`` than the video's, moved): the model's picture moved onto the video as ``parts`` have it
    (as :func:`blend` takes them) or ``still`` (the model's picture where it is, as ``parts`` were made
    from), whichever draws ``frame`` nearer over the whole picture (moved where both do). A block's last
    choice ``before`` changes only where the other is ``hysteresis`` times nearer (a choice that
    flickers costs bits and shows), the video's error counted ``favour`` times (per block);
    ``shrink``: the pictures are the picture's size over this (a divisor of BLOCK), so a block is
    BLOCK / shrink pixels of them.

    The move is right where the video shows the head where the model is a pixel or two off; where
    the video is too blurred or too coarse to show it (a blurred key, the few bits of 4 kbit/s),
    the flow follows the blur and moves a right model off: sadtalker_WDA_KatieHill's first frames at
    4 kbit/s, every block the model's, drew 25.6 dB moved against the model's own 30.1."""
    frame = np.ascontiguousarray(frame)
    options = [(parts, True)] if parts[0] is still else [(parts, True), ((still, *parts[1:]), False)]
    tried = []
    for option, moved in options:
        by_model, by_video = _block_errors(*option, frame, *before.shape, BLOCK // shrink)
        weighted = by_video if favour is None else by_video * favour
        chosen = np.where(before, by_model < hysteresis * weighted, hysteresis * by_model < weighted)
        tried.append((float(np.where(chosen, by_model, by_video).sum()), chosen, moved))
    _, chosen, moved = min(tried, key=lambda t: t[0])  # the first of equals: moved
    return chosen, moved


@njit(cache=True, fastmath=True)
def _block_errors(model, up, detail, agree, frame, rows, columns, block):  # pragma: no cover - compiled
    """(rows, columns) float64 each: per block of ``block`` pixels, the squared error against ``frame`` of the model's
    picture and of the video's sharpened by the model's detail (up + agree detail, as
    blend draws it before rounding). A row's pixels' errors first (a loop that vectorises, over the
    arrays seen flat as in _mix), then their sums per block: at 1920x1080 NumPy's whole-frame float32
    temporaries took about 100 ms a frame, this about 2."""
    by_model, by_video = np.zeros((rows, columns)), np.zeros((rows, columns))
    h, w = model.shape[:2]
    flat_model, flat_up, flat_detail = model.reshape(-1), up.reshape(-1), detail.reshape(-1)
    flat_frame, flat_agree = frame.reshape(-1), agree.reshape(-1)
    of_model, of_video = np.empty(w, np.float32), np.empty(w, np.float32)  # a row's pixels' errors
    for y in range(h):
        for x in range(w):
            p = y * w + x
            a = flat_agree[p]
            em, ev = np.float32(0.0), np.float32(0.0)
            for c in range(3):
                m, f = np.float32(flat_model[3 * p + c]), np.float32(flat_frame[3 * p + c])
                sharpened = np.float32(flat_up[3 * p + c]) + a * np.float32(flat_detail[3 * p + c])
                em += (m - f) * (m - f)
                ev += (sharpened - f) * (sharpened - f)
            of_model[x], of_video[x] = em, ev
        row = y // block
        for column in range(columns):
            span = slice(column * block, min(w, column * block + block))
            by_model[row, column] += of_model[span].sum()
            by_video[row, column] += of_video[span].sum()
    return by_model, by_video


def _carried_parts(model: np.ndarray, frame: np.ndarray, since: int,
                   carry: Callable[[np.ndarray, int], np.ndarray] | None, move: bool = True,
                   small: np.ndarray | None = None) -> VideoParts:
    """The video_parts of the layer's video ``frame`` (which shows frame ``since``) over ``model``
    (``move``: moved onto the video; ``small``: as video_parts takes it), the frame moved by ``carry`` to
    the one ``model`` draws (None: held still): what the sender's choice and both ends' drawing see."""
    return video_parts(model, frame if carry is None else carry(frame, since), move, small)


class VideoLayer:
    """What both ends hold of the layer: the video's decoder, its last frame and the model's
    blocks. The receiver reads payloads with :meth:`take` and decodes each with :meth:`decode_due`
    once its frame's parameters are known (a payload goes before them; its video is coded from the
    model's picture of its frame); the sender makes them with :meth:`make`; both draw with
    :meth:`draw`. A payload holds from its frame on; frames before it, drawn later (a receiver's
    buffer), are drawn as before it. A held video frame is drawn as ``carry`` (given to :meth:`draw`)
    moves it from its own frame to the one drawn: the face's motion since, which the parameters carry.
    With ``ahead`` (frames, the stream header's), a frame between two video frames at most that far
    before the next one is drawn from both (:meth:`draw`), once :meth:`ready` says the next is known."""

    def __init__(self, picture_size: tuple[int, int], ahead: int = 0) -> None:
        self.picture_size, self.ahead = picture_size, ahead
        self._decoder: VideoDecoder | None = None
        self._none = np.zeros(blocks_of(picture_size), dtype=bool)  # no block the model's
        self._counter: int | None = None  # the last payload's; None: waiting for a key
        #: payloads taken, not yet decoded: (frame, key, the video or None for blocks only, chosen blocks,
        #: whether the model's blocks are moved)
        self._taken: deque[tuple[int, bool, bytes | None, np.ndarray, bool]] = deque(maxlen=HELD)
        #: (first frame, the video's frame or None for the model's picture alone, chosen blocks,
        #: the frame the video's frame shows, whether the model's blocks are moved onto it)
        self._states: deque[tuple[int, np.ndarray | None, np.ndarray, int, bool]] = deque(maxlen=HELD)

    def take(self, seq: int, payload: bytes) -> bool:
        """Read the payload of frame ``seq``; False if it cannot be used (damaged, or no key since a
        loss), after which the model's picture is drawn alone until the next key."""
        if not payload:
            return self._lost(seq)
        key, only, counter = bool(payload[0] & KEY), bool(payload[0] & BLOCKS_ONLY), payload[0] >> 3
        move = not payload[0] & STILL
        if not key and (self._counter is None or counter != (self._counter + 1) % COUNTER):
            return self._lost(seq)
        before = self._none if key else (self._taken[-1][3] if self._taken else self.chosen)
        blocks = decode_blocks(before, payload[1:])
        if blocks is None or (only and (key or len(payload) != 1 + blocks[1])):
            return self._lost(seq)
        self._counter = counter
        self._taken.append((seq, key, None if only else payload[1 + blocks[1]:], blocks[0], move))
        return True

    def decode_due(self, seq: int, reference: Callable[[tuple[int, int]], np.ndarray] | None) -> bool:
        """Decode the payloads taken for frame ``seq`` (those of earlier frames still waiting were never
        due: lost), ``reference(the video's size)`` giving the model's picture of frame ``seq`` at that
        size (None: the receiver does not have this frame's parameters, so cannot draw it as the sender
        did: lost). False if one was lost, after which the model's picture is drawn alone until the next key."""
        kept = True
        while self._taken and self._taken[0][0] <= seq:
            first, key, video, chosen, move = self._taken.popleft()
            frame = None
            if first == seq and reference is not None:
                frame = self.frame if video is None else self._decode(video, key, reference)
            if frame is None:
                kept = self._lost(first)
                continue
            self._hold(first, frame, chosen, self._since if video is None else first, move)
        return kept

    def make(self, seq: int, video: bytes | None, key: bool, model: np.ndarray,
             carry: Callable[[np.ndarray, int], np.ndarray] | None,
             choose: Callable[[VideoParts, np.ndarray, np.ndarray], tuple[np.ndarray, bool]],
             reference: np.ndarray | None = None, small: np.ndarray | None = None) -> bytes | None:
        """The payload of frame ``seq`` for the sender's coded frame ``video`` (None: blocks only, the
        last frame held) coded from ``reference`` (the model's picture at the video's size; ``small``:
        ``model`` at the video's size where the sender has it, as :meth:`draw` takes it), taken as
        :meth:`take` and :meth:`decode_due` take it; its blocks and whether the model's picture is moved
        in them are ``choose(the video's parts over the model's picture ``model``, ``model``, the last
        choice)`` (:func:`choose_payload`), the decoded frame carried to ``seq`` as :meth:`draw` carries
        it. None (nothing to send) for blocks only that change nothing."""
        counter = 0 if self._counter is None else (self._counter + 1) % COUNTER
        if video is None:
            frame = self.frame
        elif reference is None:
            raise ValueError("a video frame needs the model's picture it was coded from")
        else:
            given = reference
            frame = self._decode(video, key, lambda size: given)
        if frame is None:
            raise ValueError("no frame to hold" if video is None else "the layer's own video did not decode")
        since = self._since if video is None else seq
        chosen, move = choose(_carried_parts(model, frame, since, carry, small=small), model, self.chosen)
        if video is None and np.array_equal(chosen, self.chosen) and move == self._move:
            return None
        start = self._none if key else self.chosen
        flags = int(key) | (BLOCKS_ONLY if video is None else 0) | (0 if move else STILL) | counter << 3
        data = bytes([flags]) + encode_blocks(start, chosen) + (video or b"")
        self._counter = counter
        self._hold(seq, frame, chosen, since, move)
        return data

    @property
    def chosen(self) -> np.ndarray:
        """The model's blocks as the last payload left them."""
        return self._states[-1][2] if self._states else self._none

    @property
    def frame(self) -> np.ndarray | None:
        """The video's last frame; None: the model's picture alone."""
        return self._states[-1][1] if self._states else None

    @property
    def _since(self) -> int:
        return self._states[-1][3] if self._states else -1

    @property
    def _move(self) -> bool:
        return self._states[-1][4] if self._states else True

    def ready(self, seq: int, latest: int) -> bool:
        """Whether frame ``seq`` can be drawn as it will stay once the payloads of the frames up to
        ``latest`` are decoded: it waits for none (no ``ahead``, or no video frame to draw it from:
        before the first key, after a loss, a receiver given no picture packets), or the frame
        ``ahead`` after it is known, or the first payload after it other than blocks only (a video
        frame, or a loss)."""
        if latest >= seq + self.ahead:
            return True
        current = None
        for state in self._states:
            if state[0] <= seq:
                current = state
            elif state[1] is None or state[3] == state[0]:
                return True
        return current is None or current[1] is None

    def draw(self, seq: int, model: np.ndarray, carry: Callable[[np.ndarray, int], np.ndarray] | None = None,
             small: np.ndarray | None = None) -> np.ndarray:
        """The picture of frame ``seq`` whose model's picture is ``model``; ``carry(video frame, the
        frame it shows)``: the video frame moved to frame ``seq``, at its own size (None: held still);
        ``small``: ``model`` at the video's size, where the caller has it (:func:`video_parts`).

        A frame between two video frames (its next at most ``ahead`` after it, and decoded) is drawn
        from both, each carried to it and weighted by how near it is (so are their model's blocks):
        the frame a video frame shows drifts from it as the picture moves, and meets the next one
        half way instead of jumping to it. On the nine dev crops at 4 kbit/s +0.78 dB on average and
        the 5th percentile +1.7 (docs/picture_layer.md). The two carried frames are mixed at the
        video's size and their parts made once (0.05 dB under making and blending each's, for half the
        time), and their blocks' weights mixed as they are."""
        while len(self._states) > 1 and self._states[1][0] <= seq:
            self._states.popleft()
        if not self._states or self._states[0][0] > seq:
            return model
        _, frame, chosen, since, move = self._states[0]
        if frame is None:
            return model
        if carry is None or (after := self._next(seq, frame.shape)) is None:
            parts = _carried_parts(model, frame, since, carry, move, small)
            return blend(parts, chosen, self.picture_size, frame.shape[1::-1])
        nearer, next_frame, next_chosen = after
        weight = (seq - since) / (nearer - since)
        mixed = cv2.addWeighted(carry(frame, since), 1.0 - weight, carry(next_frame, nearer), weight, 0.0)
        size = frame.shape[1::-1]
        return blend(video_parts(model, mixed, move, small), (1.0 - weight) * chosen + weight * next_chosen,
                     self.picture_size, size)

    def _next(self, seq: int, shape: tuple[int, ...]) -> tuple[int, np.ndarray, np.ndarray] | None:
        """(frame, the video's frame, its chosen blocks) of the first video frame after frame ``seq``
        where a picture between them is drawn from both: at most ``ahead`` after it, with nothing
        but blocks only between, of the same size."""
        for first, frame, chosen, since, _ in self._states:
            if first <= seq or (frame is not None and since != first):
                continue
            if frame is None or first > seq + self.ahead or frame.shape != shape:
                return None
            return first, frame, chosen
        return None

    def _decode(self, video: bytes, key: bool, reference: Callable[[tuple[int, int]], np.ndarray]
                ) -> np.ndarray | None:
        """The (h, w, 3) RGB frame of a payload's ``video`` (:meth:`VideoEncoder.encode`); None if it does
        not decode (or no key since the decoder was lost)."""
        if key:
            self._decoder = VideoDecoder(video_size(self.picture_size, max(self.picture_size)))
        return None if self._decoder is None else self._decoder.decode(video, key, reference)

    def _hold(self, seq: int, frame: np.ndarray | None, chosen: np.ndarray, since: int, move: bool = True) -> None:
        self._states.append((seq, frame, chosen, since, move))

    def _lost(self, seq: int) -> bool:
        self._decoder, self._counter = None, None
        self._taken.clear()
        self._hold(seq, None, self._none, seq)
        return False
