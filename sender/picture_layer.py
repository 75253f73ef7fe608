"""The picture layer at the sender: a closed loop that renews the receiver's picture under a rate.

The sender runs the receiver's own view (receiver.face_view.PictureView) on the parameters the
receiver will decode (``protocol.encoder.PacketEncoder.reconstruction``), so it knows, bit for
bit, what the receiver draws. At regular steps paid for by the rate left after the parameters,
it codes half the difference between the real frame and that picture (codec/renewal.py), hands
the coded residual to its own view exactly as the receiver will, and sends it in the picture
layer's packets, ahead of the frame's own. Renewing often with small images beat renewing
rarely with large ones on the moving dev clips (docs/picture_layer.md): the picture goes stale
in the half second after a renewal, however sharp it was.
"""

from collections import deque

import cv2
import numpy as np

from facedeform.codec.face_model import BaseFace
from facedeform.codec.renewal import decode_renewal, encode_renewal
from facedeform.protocol.stream import Header, PacketEncoder, stream_size
from facedeform.receiver.face_view import PictureView, residual_of

#: A renewal gets RENEWAL_BYTES of what the layer saves, renewals coming as often as that allows,
#: but at least every PERIOD seconds (with fewer bytes) and at most every frame (with more).
RENEWAL_BYTES, PERIOD = 250, 0.5
WINDOW = 2.0  # seconds over which the whole stream must keep within MARGIN of its rate
MARGIN = 1.05
PACKING = 16  # bytes a renewal's packet adds to its image (sync, type, length, numbers, check)
MIN_RENEWAL = 60  # bytes: the smallest WebP worth sending
SHARP = 45.0  # dB: a picture this close to the frame is not renewed
#: A renewal is sent only if it brings the frame's picture at least this many dB closer to the
#: frame: below it, a renewal's coding noise costs about what it corrects, and adds up (a still
#: speaker's picture went from VMAF 30 to 10 at 4 kbit/s when every renewal was sent).
GAIN = 1.0
#: Over datagrams, seconds after which a renewal is the whole picture again, not a residual: a
#: receiver that joined late or lost a renewal draws what the sender does from then on. Byte
#: streams (files, pipes, TCP) lose nothing and start at the beginning, so they never pay for it
#: (a whole picture shows less than a residual for its bytes: 0.7-1.1 dB on pcavs_Pose_Source).
WHOLE_EVERY = 1.0


class PictureLayer:
    """Renews the receiver's picture of ``face`` (which has a reference picture) within ``bitrate``
    bit/s for the whole stream after its header, of which the parameters take what they take.

    :meth:`step` takes each frame after the encoder coded it and returns the picture layer's
    packets to send before that frame's packets; ``sealed``: packets are sealed (each costs a
    sync byte more on a byte stream); ``datagrams``: they go over a lossy link (WHOLE_EVERY).
    :attr:`picture` is what the receiver draws of the frame.
    """

    def __init__(self, face: BaseFace, header: Header, bitrate: float, sealed: bool = False,
                 datagrams: bool = False) -> None:
        if face.picture is None:
            raise ValueError("the picture layer needs a face with a reference picture")
        height, width = face.picture.image.shape[:2]
        self.size = (width, height)
        self._view = PictureView(header, face, self.size)
        self._frame_bits = bitrate / header.fps
        self._sealed = sealed
        window = max(1, round(WINDOW * header.fps))
        self._recent: deque[int] = deque(maxlen=window - 1)  # bits of the last frames sent
        self._window_bits = MARGIN * self._frame_bits * window
        self._parameter_bits = 0.0  # the parameters' bits per frame, a running mean
        self._saved = 0.0  # bits the layer may spend now
        self._period = PERIOD * header.fps  # frames
        self._whole_every = WHOLE_EVERY * header.fps if datagrams else None
        self._last_whole = 0  # the frame of the last whole renewal (none before the call starts)
        self.picture: np.ndarray | None = None
        self.renewals = self.bits = 0

    def step(self, seq: int, frame_bgr: np.ndarray, params: np.ndarray, encoder: PacketEncoder,
             frame_packets: list[bytes]) -> list[bytes]:
        """The picture layer's packets for frame ``seq`` (BGR, any size: scaled to the picture's),
        whose decoded parameters are ``params`` and packets ``frame_packets``."""
        spent = 8 * stream_size(frame_packets, self._sealed)
        count = len(self._recent) + 1
        self._parameter_bits += (spent - self._parameter_bits) / min(count, 25)
        layer = max(0.0, self._frame_bits - self._parameter_bits)
        share = min(max(8 * RENEWAL_BYTES, layer), layer * self._period)  # bits a renewal waits for
        self._saved = min(self._saved + layer, 2 * share)
        drawn = self._view.render(params, seq)
        packets: list[bytes] = []
        budget = min(self._saved, self._window_bits - sum(self._recent) - spent - self._parameter_bits)
        if budget >= 8 * (MIN_RENEWAL + PACKING) and self._saved >= share:
            rgb = cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2RGB)
            if rgb.shape[1::-1] != self.size:
                rgb = cv2.resize(rgb, self.size, interpolation=cv2.INTER_AREA)
            before = _psnr(drawn, rgb)
            if before < SHARP:
                whole = self._whole_every is not None and seq - self._last_whole >= self._whole_every
                data = encode_renewal(rgb if whole else residual_of(rgb, drawn), int(budget / 8) - PACKING)
                coded = None if data is None else decode_renewal(data, self.size)  # as the receiver will
                if coded is not None and not whole:
                    after = np.clip(drawn + 2 * (coded.astype(np.int16) - 128), 0, 255)
                    coded = coded if _psnr(after, rgb) >= before + GAIN else None
                if data is not None and coded is not None:
                    packets = encoder.picture(seq, data, whole)
                    self._last_whole = seq if whole else self._last_whole
                    self._view.renew(seq, coded, whole)
                    drawn = self._view.render(params, seq)
                    self.renewals += 1
        bits = 8 * stream_size(packets, self._sealed)
        self._saved -= bits
        self.bits += bits
        self._recent.append(spent + bits)
        self.picture = drawn
        return packets


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    error = float(np.mean((a.astype(np.float32) - b) ** 2))
    return 10 * np.log10(255 ** 2 / max(error, 1e-10))
