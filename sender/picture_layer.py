"""The picture layer at the sender: the real frame as a small VP9 video coded from the model's picture,
under the rate the parameters leave (codec/render/frame_video.py).

The sender runs the receiver's own view (receiver.face_view.PictureView) on the parameters the
receiver will decode (``protocol.encoder.PacketEncoder.reconstruction``) and the receiver's own
layer (codec.render.frame_video.VideoLayer) on every payload it sends, so it knows, bit for bit, what
the receiver draws. For each frame it may send, it codes the frame scaled down, decodes it as
the receiver will, and chooses the blocks where the model's picture is nearer the frame than the
video's, and whether the model's picture there is moved onto the video or drawn where it is.
"""

from collections import deque
from collections.abc import Callable
from math import ceil

import cv2
import numpy as np

from facedeform.codec.model.face_model import BaseFace
from facedeform.codec.render.frame_video import (
    HELD,
    VideoEncoder,
    VideoLayer,
    blocks_in,
    choose_payload,
    drawn_size,
    shrunk,
    video_size,
)
from facedeform.protocol.stream import Header, PacketEncoder, stream_size
from facedeform.sender.config import PARAMETER_FLOOR, parameter_rate

WINDOW = 2.0  # seconds over which the whole stream must keep within MARGIN of its rate
MARGIN = 1.0  # the layer fills the window to the rate: the parameters' own bursts take the 10 % above
PACKING = 9  # bytes a layer packet adds to its payload (sync, type, length, frame, size, offset, check)
#: Bytes of the smallest video packet to plan for: the codec's smallest frame at these sizes (about 20
#: bytes), its packing and blocks, and room for what moves. Below a rate that pays for one every
#: frame, frames are sent every second, third... frame: the encoder's rate control, told the frames
#: it really gets, then keeps to the rate (skipping frames it was told of made it spend the
#: skipped frames' bits on the next, which the rate then skipped in turn). 60 rather than 40 (a
#: frame every 5th frame at 4 kbit/s, not every 4th): fewer, better frames, which the model carries
#: between them; 75 rather than 60 once the frames went evenly (BURST; every 6th at 4 kbit/s, 4th at 6,
#: 3rd at 8): on the nine dev crops +0.06 / +0.11 / +0.14 / +0.07 dB and VMAF +1.1 / +1.3 / +1.4 /
#: +0.6 at 4 / 6 / 8 / 10 kbit/s, the 5th percentile +0.06 at 4, lower above (docs/picture_layer.md;
#: these with SVT-AV1, the layer's codec until stream version 17).
SMALLEST = 75
#: The encoder's rate control misses at these sizes (SVT-AV1's by up to 30 % over on
#: sadtalker_WDA_KatieHill at 30 kbit/s, 20 % under on lipnet): it is asked for the video's
#: share as planned, and a video frame is skipped while the video has spent more than its share
#: of what the parameters really leave (skips spread evenly, where a full 2-second window once
#: held a stale frame for 16 frames).
#: Seconds of its share the video may save up: less than one video frame's worth at 4 kbit/s, so that
#: the frames go evenly. At 0.5 a quiet spell saved up two, which then went back to back and, with
#: the video's frames over their plan, filled the 2-second window before a head turn (sadtalker_RD_Radio34
#: at 4 kbit/s: no video for frames 81-96 of its turn). The nine dev crops: +0.07 / -0.01 / +0.03 / +0.03
#: dB at 4 / 6 / 8 / 10 kbit/s (docs/picture_layer.md).
BURST = 0.15
#: A video frame goes only if the 2-second window has room for this many times the usual one. 1.5 until
#: libvpx dropped frames that would overrun its buffer (codec/render/vp9.py); since, on the nine dev
#: crops against 1.5: 1.2 +0.07 / +0.05 dB at 4 / 10 kbit/s, 1.0 +0.12 / +0.07, 0.8 +0.19 / +0.07 (every
#: clip up at 4; the costliest 2-second window at 4 kbit/s 1.077, at 10 1.057), 0.6 +0.19 / +0.12 but its 5th
#: percentile 0.15 dB lower at 4 and its costliest window 1.126 (pcavs_Pose_Source), past the 1.10 allowed.
HEADROOM = 0.8
#: A coded video frame larger than the window's room by more than this share of the window (of the 0.1
#: the rate allows above it, the rest left to the parameters' bursts) is not sent, and the next video frame
#: goes as a key (libvpx has moved on to the frame not sent). libvpx's frame sizes are not bounded: with
#: its buffer full it codes a frame that changes much at a fine quantiser, and frames of 2.7-5 times the
#: usual one had taken the costliest 2-second window on the nine dev crops to 1.37 times the rate at 3
#: kbit/s (sadtalker_WDA_KatieHill) and 1.13 at 5 (pcavs_Pose_Source). Half a usual frame instead cost the
#: crops 0.13 and 0.16 dB at 4 and 10 kbit/s (each key starts again from the model's picture), 0.05 of
#: the window 0.04 at 4 (docs/picture_layer.md).
OVERRUN = 0.08
PARAMETER_MEMORY = 25  # frames over which the parameters' bits are averaged
BLOCKS_SHARE = 0.1  # of the layer's rate, for payloads of blocks only between video frames
#: A block goes back to the model between video frames only if the model's picture is this
#: many times nearer the frame there than the held video frame's.
BLOCKS_ONLY_GAIN = 2.0
#: The video's error counts this many times in the blocks around the mouth: a small video's mouth,
#: a few frames a second, reads to the tracker as a mouth that hardly moves (mouth-opening
#: correlation 0.47 on pcavs_Pose_Source at 10 kbit/s with the video's mouth throughout, 0.89
#: with the model's). At 4 kbit/s this took the correlation from 0.74 to 0.90 on tpsmm_driving,
#: 0.47 to 0.76 on pcavs_Pose_Source, 0.88 to 0.94 on vretalking_face4, for at most 0.23 dB.
MOUTH = 3.0
#: The video's larger side, as a share of the picture's, by the layer's bit/s per 256x256 pixels:
#: 128 pixels beat 64 at 4 and 10 kbit/s on three dev clips, on PSNR, SSIM and VMAF (pcavs_Pose_Source
#: at 10: 28.5 dB and VMAF 34 against 27.3 and 18), and 256 beat 128 at 30 on two of three
#: (docs/picture_layer.md). At 1920x1080 and 60 kbit/s (1,860 per 256x256) a quarter (480x270)
#: beat a half on a moving clip, 26.81 dB against 26.35, and lost 0.14 dB on a still one, with the
#: sender 1.6-1.7 times as fast (docs/hd.md).
SIDES = ((2_048, 0.25), (20_000, 0.5), (float("inf"), 1.0))
#: Over datagrams, seconds between keys: a receiver that lost a packet or joined late draws the
#: layer again from the next one. Byte streams (files, pipes, TCP) lose nothing and start at the
#: beginning, so they send one key only.
KEY_EVERY = 1.0
#: The same while the receiver reports a link that loses nothing (sender/link.py: the session sets
#: :attr:`PictureLayer.key_every`): at 4 kbit/s a key a second had taken most of the layer's share.
LEAN_KEY_EVERY = 4.0
#: The sender chooses the layer's blocks on the pictures shrunk by a whole number that divides BLOCK and
#: both sides, as far as they stay at least the video's size and their larger side at least this many
#: pixels: at 1920x1080 with a 960x540 video by 2 (a block is then 16x16 pixels). The receiver draws the
#: picture whole as before; only which blocks the sender hands to the model is judged on fewer pixels.
#: Drawing the model's picture at 1920x1080 every frame had cost the sender 15 ms of its 47 (docs/hd.md).
#: Judged on fewer pixels than the video's, the choice lost the model's and the video's detail alike:
#: the bundled clip at 10 kbit/s with a 180x144 video, 32.85 dB chosen at 360x288, 32.84 at 180x144,
#: 31.53 at 90x72.
CHOICE_SIDE = 480
#: The layer's least bit/s per 256x256 pixels: below it, its few frames cost the parameters more
#: than they show (liveportrait_d11 at 1.5 kbit/s: 27.6 dB with a layer of 0.4 kbit/s, 28.2
#: with the parameters alone).
LEAST = 1_500
#: Over datagrams a key that has waited twice key_every for room goes once the window has room for this
#: share of the usual key: forced whole, it had taken the bundled clip's first 2 s to 1.21 times the rate
#: at 8 kbit/s to a receiver that does not report, its first key still in the window.
OVERDUE = 0.5


def layer_rate(bitrate: float) -> float:
    """bit/s the layer plans on at ``bitrate`` for the whole stream (the parameters take at most
    their floor's worth at the start; what they leave unused goes to the layer as the call goes)."""
    return bitrate - min(parameter_rate(bitrate), PARAMETER_FLOOR)


def layer_video_size(bitrate: float, picture_size: tuple[int, int]) -> tuple[int, int]:
    """(w, h) of the layer's video at ``bitrate`` for the whole stream, for a picture of ``picture_size`` (SIDES)."""
    width, height = picture_size
    share = next(s for most, s in SIDES if layer_rate(bitrate) * 256 ** 2 / (width * height) < most)
    return video_size(picture_size, max(width, height) * share)


def choice_shrink(picture_size: tuple[int, int], video: tuple[int, int]) -> int:
    """What the sender's choice shrinks a picture of ``picture_size`` (w, h) with a ``video`` of that
    size by (CHOICE_SIDE)."""
    w, h = picture_size
    return next(s for s in (4, 2, 1) if s == 1 or (
        w % s == 0 and h % s == 0 and w // s >= video[0] and h // s >= video[1] and max(w, h) // s >= CHOICE_SIDE))


def layer_pays(bitrate: float, picture_size: tuple[int, int], parameters: float = 0.0) -> bool:
    """Whether a layer at ``bitrate`` for a picture of ``picture_size`` (w, h) is worth sending, where
    the parameters cost ``parameters`` bit/s when that is more than the layer plans on leaving them
    (over datagrams, with their copies, keyframes and the header's repeats: several kbit/s)."""
    room = min(layer_rate(bitrate), bitrate - parameters)
    return room * 256 ** 2 / (picture_size[0] * picture_size[1]) >= LEAST


class PictureLayer:
    """The layer of ``face`` (which has a reference picture) within ``bitrate`` bit/s for the whole
    stream after its header, of which the parameters take what they take.

    :meth:`step` takes each frame after the encoder coded it and returns the layer's packets to
    send before that frame's packets; ``sealed``: packets are sealed (each costs a sync byte
    more on a byte stream); ``datagrams``: they go over a lossy link (KEY_EVERY); ``recent``: the
    caller's window of the bits the stream sent for each frame before this one (WINDOW seconds less a
    frame, the newest last), to which it adds each frame's, the layer's packets included, after the step;
    ``parameters``: bit/s the parameters are known to take where more than they aim at (over datagrams,
    with their copies and the header's repeats: at 10 kbit/s on liveportrait_d12 6.6 kbit/s, where they
    aim at 2; planned on the 2, the layer's first video frames had taken the first 2 s to 1.23 times
    the rate); ``repeats(seq, n)``: bits of the header's repeats that go with each of the n frames after
    frame ``seq`` (over datagrams: a few hundred bytes each, which a window can hold one more of than
    the parameters' mean foresees; sadtalker_WDA_KatieHill's had taken a window to 1.12 times the rate
    at 10 kbit/s).
    :attr:`picture` is what the receiver draws of the last frame stepped, drawn when it is read (the
    layer's choices do not need it: at 1920x1080 drawing it cost the sender 5 ms a frame, and the
    model's picture whole another 15 where the choice is made on a smaller view, :data:`CHOICE_SIDE`).
    """

    def __init__(self, face: BaseFace, header: Header, bitrate: float, recent: deque[int], sealed: bool = False,
                 datagrams: bool = False, parameters: float = 0.0,
                 repeats: Callable[[int, int], np.ndarray] | None = None) -> None:
        from facedeform.receiver.face_view import PictureView

        if face.picture is None:
            raise ValueError("the picture layer needs a face with a reference picture")
        height, width = face.picture.image.shape[:2]
        self.size = (width, height)
        self._view = PictureView(header, face, self.size)
        self._layer = VideoLayer(self.size, header.ahead)
        self._frame_bits = bitrate / header.fps
        self._sealed = sealed
        layer = layer_rate(bitrate)
        self._video_size = layer_video_size(bitrate, self.size)
        self._shrink = shrink = choice_shrink(self.size, self._video_size)
        self._look = self._view if shrink == 1 else PictureView(header, face, (width // shrink, height // shrink))
        #: (frame, parameters) of the frames stepped that :meth:`pictures` has not drawn: at most HELD, as
        #: the receiver holds, and how many it has told the whole view to expect
        self._waiting: deque[tuple[int, np.ndarray]] = deque(maxlen=HELD)
        self._told = -1
        video = (1 - BLOCKS_SHARE) * layer  # bit/s
        self._every = max(1, ceil(header.fps * 8 * SMALLEST / video))
        sent = header.fps / self._every  # video packets a second
        self._encoder_rate = (video - 8 * PACKING * sent, sent)
        self._encoder: VideoEncoder | None = None  # made with the first key (_first_key)
        self._fps = header.fps
        #: the parameters' bits a frame, a running mean, from what they aim at or, where more, are known to take
        self._parameter_bits = max(parameter_rate(bitrate), parameters) / header.fps
        self._repeats = repeats
        self._repeat_bits: float | None = None  # the header's repeats' share of them, a running mean
        self._credit = 0.0  # bits the video may still spend, against its share so far
        self._recent = recent
        self._window_bits = MARGIN * self._frame_bits * ((recent.maxlen or 0) + 1)
        self._blocks_bits = BLOCKS_SHARE * layer / header.fps  # a frame's share for blocks only
        self._saved = 0.0  # bits saved for blocks only
        self._size = 8.0 * SMALLEST  # bits of a video packet, a running mean
        self._key_size = 0.0  # bits of a key's packets, a running mean
        #: seconds between keys (None: the first only)
        self.key_every: float | None = KEY_EVERY if datagrams else None
        self._last_key: int | None = None
        self._asked = False  # a key asked for before its time (:meth:`key_soon`)
        self._restart = False  # a coded frame was not sent (OVERRUN): the next video frame is a key
        self._last_video: int | None = None  # the last frame a video frame went with
        self._last: int | None = None  # the last frame stepped
        self.packets = self.bits = 0

    def step(self, seq: int, frame_bgr: np.ndarray, params: np.ndarray, encoder: PacketEncoder,
             frame_packets: list[bytes], repeated: int = 0) -> list[bytes]:
        """The layer's packets for frame ``seq`` (BGR, any size: scaled to the picture's), whose
        decoded parameters are ``params`` and packets ``frame_packets``, of which ``repeated`` bits are
        the header's repeats."""
        spent = 8 * stream_size(frame_packets, self._sealed)
        self._saved = min(self._saved + self._blocks_bits, 8.0 * SMALLEST)
        self._waiting.append((seq, params))
        model = self._look.model_picture(params, seq)  # at the size the choice is made at
        packets: list[bytes] = []
        if self._repeats is not None and self._repeat_bits is None:  # from what the next 2 seconds hold
            self._repeat_bits = float(np.mean(self._repeats(seq - 1, self._recent.maxlen or 1)))
        room = self._room(seq, spent)
        since = None if self._last_key is None else (seq - self._last_key + self._every) / self._fps
        every = self.key_every
        waiting = overdue = False
        if since is not None and every is not None:
            # a key due waits, and the video with it, until the window has room for it; after twice
            # key_every, until it has room for OVERDUE of it
            waiting, overdue = since > every or self._asked, since > 2 * every
        key = since is None or (waiting and room >= (OVERDUE if overdue else 1.0) * self._key_size)
        self._parameter_bits += (spent - self._parameter_bits) / PARAMETER_MEMORY
        if self._repeat_bits is not None:
            self._repeat_bits += (repeated - self._repeat_bits) / PARAMETER_MEMORY
        share = (1 - BLOCKS_SHARE) * max(0.0, self._frame_bits - self._parameter_bits)
        self._credit = min(self._credit + share, BURST * share * self._fps)
        due = self._last_video is None or seq - self._last_video >= self._every
        if due and (key or (not waiting and self._credit >= 0 and room >= HEADROOM * self._size)):
            packets = self._send(seq, self._sized(frame_bgr), params, model, key or self._restart, encoder, room)
        elif self._layer.frame is not None and min(self._saved, room) >= 8 * (PACKING + 4):
            rgb = self._looked(self._sized(frame_bgr))
            favour = self._favour()
            data = self._layer.make(seq, None, False, model, self._look.carry, lambda parts, still, before:
                                    choose_payload(parts, still, rgb, before, BLOCKS_ONLY_GAIN, favour, self._shrink))
            packets = [] if data is None else encoder.picture(seq, data)
            self._saved -= 8 * stream_size(packets, self._sealed)
        bits = 8 * stream_size(packets, self._sealed)
        self.packets += bool(packets)
        self.bits += bits
        self._last = seq
        return packets

    def _room(self, seq: int, spent: float) -> float:
        """Bits the layer may add to frame ``seq``'s ``spent`` so that every 2-second window this frame
        falls in keeps within the rate, with room left in it for the parameters of the frames still to
        come (and the header's repeats among them)."""
        recent = np.asarray(self._recent, dtype=np.float64)[::-1]  # newest first
        span = self._recent.maxlen or 0
        kept = np.r_[0.0, np.cumsum(recent)]  # bits of the newest 0, 1, ... frames before this one
        kept = np.r_[kept, np.full(span + 1 - len(kept), kept[-1])]
        ahead = np.full(span, self._parameter_bits)
        if self._repeats is not None:  # where they fall, not spread
            ahead += self._repeats(seq, span) - self._repeat_bits
        ahead = np.r_[0.0, np.cumsum(ahead)]  # bits of the next 0, 1, ... frames
        return self._window_bits - spent - float(np.max(kept + ahead[::-1]))

    def pictures(self, final: bool = False) -> list[tuple[int, np.ndarray]]:
        """(frame, what the receiver draws of it) of the frames stepped whose pictures are known now
        (:meth:`VideoLayer.ready`; ``final``: every one, the call having ended), in order, each once;
        ask after every step."""
        for seq, params in self._waiting:
            if seq > self._told and self._layer.ahead:
                self._view.expect(params, seq)
        self._told = self._last if self._last is not None else -1
        drawn = []
        while self._waiting and (final or self._layer.ready(self._waiting[0][0], self._told)):
            seq, params = self._waiting.popleft()
            drawn.append((seq, self._layer.draw(seq, self._view.model_picture(params, seq), self._view.carry)))
        return drawn

    def _favour(self) -> np.ndarray:
        """Per block, how many times the video's error counts: MOUTH in the mouth's blocks."""
        return np.where(blocks_in(self._look.mouth_box, self.size), MOUTH, 1.0)

    def key_soon(self) -> None:
        """The receiver reported a loss: the next key goes as soon as the window has room for it, not at
        its time. A receiver that lost a packet of the layer draws the model's picture alone until then;
        its reports count the layer's lost payloads beside the frames' (protocol/report.py, version 3;
        bench_loss.py layer --reports at 10 kbit/s: 24.25 -> 25.15 dB at 5 % random loss, 24.79 -> 26.35
        in bursts of 3, against the ask on the frames' losses alone)."""
        self._asked = True

    def close(self) -> None:
        """Ends the video's encoder (after the last frame)."""
        if self._encoder is not None:
            self._encoder.close()

    def _sized(self, frame_bgr: np.ndarray) -> np.ndarray:
        """``frame_bgr`` at the picture's size."""
        same = frame_bgr.shape[1::-1] == self.size
        return frame_bgr if same else cv2.resize(frame_bgr, self.size, interpolation=cv2.INTER_AREA)

    def _looked(self, bgr: np.ndarray) -> np.ndarray:
        """``bgr`` (at the picture's size) in RGB at the size the choice is made at."""
        return cv2.cvtColor(shrunk(bgr, self._look.size), cv2.COLOR_BGR2RGB)

    def _send(self, seq: int, bgr: np.ndarray, params: np.ndarray, model: np.ndarray, key: bool,
              encoder: PacketEncoder, room: float) -> list[bytes]:
        """The packets of a video frame (a key if ``key``) for frame ``seq`` of parameters ``params``,
        coded from the model's picture of it (codec/render/frame_video.VideoEncoder), if the window's
        ``room`` (bits) can hold it (OVERRUN)."""
        favour, looked = self._favour(), self._looked(bgr)
        small = shrunk(looked, self._video_size)  # (from the choice's size: at 1080p 1 ms, from the frame's 4)
        drawn = self._look.size == drawn_size(self.size, self._video_size)  # the picture it is coded from
        reference = shrunk(model, self._video_size) if drawn else \
            self._view.reference_picture(params, seq, self._video_size)
        if self._encoder is None:
            self._encoder = VideoEncoder(self._video_size, *self._encoder_rate)
        video = self._encoder.encode(small, reference, key)
        if not video:  # dropped by libvpx: the next frame is tried instead
            return []
        if self._last_key is not None and 8 * len(video) > room + OVERRUN * self._window_bits:
            self._restart = True
            return []
        self._restart = False
        data = self._layer.make(seq, video, key, model, self._look.carry, lambda parts, still, before:
                                choose_payload(parts, still, looked, before, favour=favour, shrink=self._shrink),
                                reference, reference if drawn else None)
        packets = [] if data is None else encoder.picture(seq, data)
        bits = 8 * stream_size(packets, self._sealed)
        if self._last_key is not None:  # the first key is the call's own: the window alone holds it
            self._size += (bits - self._size) / 4
            self._credit -= bits
        if key:
            self._key_size = bits if self._last_key is None else (self._key_size + bits) / 2
        self._last_key = seq if key else self._last_key
        self._asked = self._asked and not key
        self._last_video = seq
        return packets
