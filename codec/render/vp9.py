"""VP9 with an outside reference: libvpx, the copy PyAV's wheel carries, called through ctypes.

Why VP9 and not AV1 for the picture layer's video: both ends already hold the model's picture of
every frame, bit for bit, and libvpx lets a caller put a picture of its own into a reference slot
of its encoder and of its decoder (``VP8_SET_REFERENCE``), so each video frame is coded from the
model's picture as well as from the last video frame. SVT-AV1 and dav1d have no such call, and
PyAV exposes no codec controls at all, hence ctypes. On the nine dev clips' 256x256 crops (a
128x128 video every 6th frame, benchmarks/bench_video_codecs.py) the frames coded so came out 2.2-7.0
dB above SVT-AV1's at 2.3 kbit/s (29.47 dB against 26.03 on average) and 0.8-3.2 at 7, and a
call's first frame costs 40-260 bytes instead of 210-550: it is coded from the model's picture after
a flat grey key of a dozen bytes (docs/picture_layer.md).

Only what the layer needs is bound: one-pass CBR in real time without lag, keys on request, the
golden slot set before a frame, frames dropped once coded where they would overrun the rate. The
configuration structure is filled by libvpx's own defaults and changed at offsets checked against
those defaults when the library is loaded; a libvpx whose layout differs is refused
(:class:`Unavailable`), not guessed at.
"""

import ctypes
import glob
import os
from functools import lru_cache

import numpy as np

from facedeform.common.errors import FdError

#: Slots of libvpx's references (vpx_ref_frame_type_t) and its per-frame encoding flags.
LAST, GOLDEN, ALTREF = 1, 2, 4
SLOTS = (LAST, GOLDEN, ALTREF)  # all three: what a key leaves holding the model's picture
_FORCE_KEY, _KEEP_GOLDEN = 1, 1 << 22  # VPX_EFLAG_FORCE_KF, VP8_EFLAG_NO_UPD_GF
_SET_REFERENCE, _CPU_USED, _DROP = 1, 13, 66  # VP8_SET_REFERENCE, VP8E_SET_CPUUSED, VP9E_SET_POSTENCODE_DROP
_I420, _REALTIME = 0x102, 1  # VPX_IMG_FMT_I420, VPX_DL_REALTIME
_ENCODER_ABI, _DECODER_ABI = 39, 12  # libvpx 1.16's VPX_ENCODER_ABI_VERSION, VPX_DECODER_ABI_VERSION
#: libvpx's speed in real time: its slower search (3) for videos of at most SLOW_PIXELS, else 5. On the
#: nine dev crops (a 128x128 video) 3 gained 0.31 dB at 4 kbit/s and 0.30 at 10, every clip up, once
#: frames that would overrun the buffer were dropped (:meth:`Encoder.encode`); without that its frames
#: had taken the costliest 2-second window at 4 kbit/s to 1.173 times the rate. It costs 7.6 ms a
#: frame at 128x128 against 0.5, 28 at 256x256 against 2: at 640x512 and 60 kbit/s (a 320x256 video)
#: it had slowed the sender from 33 frames/s to 22. 4: +0.03 and -0.06 dB; 7: -0.24 and -0.20.
SLOW, FAST, SLOW_PIXELS = 3, 5, 160 * 160
#: libvpx's rate control counts in whole kbit/s: the encoder is told a clock this many times faster
#: and a rate this many times higher, the same bits a frame, so that 2.3 kbit/s is not 2.
_CLOCK = 10
#: The encoder's buffer, ms of the real clock: how far its rate control lets a frame run over its share,
#: as real-time VP9 is usually given it. A frame that would empty it is dropped once coded; with half of
#: it, libvpx dropped so often that it lost 0.18 dB at 4 kbit/s (the rate's windows kept either way).
_BUFFER_MS, _BUFFER_START_MS, _BUFFER_AIM_MS = 1000, 500, 600
_FINEST, _COARSEST = 4, 63  # the quantiser's range


class Unavailable(FdError):
    """No libvpx with the layout this module knows (a one-line error, not a guess at its layout)."""


class _Image(ctypes.Structure):  # vpx_image_t
    _fields_ = [("fmt", ctypes.c_int), ("cs", ctypes.c_int), ("range", ctypes.c_int),
                ("w", ctypes.c_uint), ("h", ctypes.c_uint), ("bit_depth", ctypes.c_uint),
                ("d_w", ctypes.c_uint), ("d_h", ctypes.c_uint), ("r_w", ctypes.c_uint), ("r_h", ctypes.c_uint),
                ("x_chroma_shift", ctypes.c_uint), ("y_chroma_shift", ctypes.c_uint),
                ("planes", ctypes.c_void_p * 4), ("stride", ctypes.c_int * 4), ("bps", ctypes.c_int),
                ("user_priv", ctypes.c_void_p), ("img_data", ctypes.c_void_p), ("img_data_owner", ctypes.c_int),
                ("self_allocd", ctypes.c_int), ("fb_priv", ctypes.c_void_p)]


class _Reference(ctypes.Structure):  # vpx_ref_frame_t
    _fields_ = [("frame_type", ctypes.c_int), ("img", _Image)]


#: Indices (in 32-bit words) of vpx_codec_enc_cfg_t's fields changed, with libvpx's defaults there.
_CONFIG = {"threads": (1, None), "w": (3, 320), "h": (4, 240), "timebase": (7, 1), "lag": (11, 25),
           "resize_down": (17, 30), "end_usage": (18, 0), "bitrate": (28, 256), "finest": (29, 0),
           "coarsest": (30, 63), "buffer": (33, 6000), "buffer_start": (34, 4000), "buffer_aim": (35, 5000),
           "key_mode": (40, 1)}


@lru_cache(maxsize=1)
def _library() -> tuple[ctypes.CDLL, ctypes.c_void_p, ctypes.c_void_p]:
    """(libvpx, its VP9 encoder's interface, its decoder's), checked against the layouts bound here."""
    import av

    here = os.path.dirname(av.__file__)
    found = [path for pattern in ("libvpx*.so*", "libvpx*.dylib", "*vpx*.dll")
             for folder in (here + ".libs", os.path.join(here, ".dylibs"), os.path.join(here, os.pardir, "av.libs"))
             for path in glob.glob(os.path.join(folder, pattern))]
    if not found:
        raise Unavailable("PyAV's wheel carries no libvpx: the picture layer needs it")
    try:
        lib = ctypes.CDLL(found[0])
    except OSError as exc:
        raise Unavailable(f"PyAV's libvpx would not load: {exc}") from exc
    c = ctypes
    lib.vpx_codec_enc_config_default.argtypes = [c.c_void_p, c.c_void_p, c.c_uint]
    lib.vpx_codec_enc_init_ver.argtypes = [c.c_void_p, c.c_void_p, c.c_void_p, c.c_long, c.c_int]
    lib.vpx_codec_dec_init_ver.argtypes = [c.c_void_p, c.c_void_p, c.c_void_p, c.c_long, c.c_int]
    lib.vpx_codec_encode.argtypes = [c.c_void_p, c.c_void_p, c.c_int64, c.c_ulong, c.c_long, c.c_ulong]
    lib.vpx_codec_get_cx_data.restype = c.c_void_p
    lib.vpx_codec_get_cx_data.argtypes = [c.c_void_p, c.c_void_p]
    lib.vpx_codec_decode.argtypes = [c.c_void_p, c.c_char_p, c.c_uint, c.c_void_p, c.c_long]
    lib.vpx_codec_get_frame.restype = c.c_void_p
    lib.vpx_codec_get_frame.argtypes = [c.c_void_p, c.c_void_p]
    lib.vpx_codec_destroy.argtypes = [c.c_void_p]
    lib.vpx_img_wrap.restype = c.c_void_p
    lib.vpx_img_wrap.argtypes = [c.c_void_p, c.c_int, c.c_uint, c.c_uint, c.c_uint, c.c_void_p]
    encoder = c.cast(c.addressof(c.c_char.in_dll(lib, "vpx_codec_vp9_cx_algo")), c.c_void_p)
    decoder = c.cast(c.addressof(c.c_char.in_dll(lib, "vpx_codec_vp9_dx_algo")), c.c_void_p)
    config = (c.c_uint32 * 256)()
    if lib.vpx_codec_enc_config_default(encoder, config, 0) != 0 or any(
            default is not None and config[i] != default for i, default in _CONFIG.values()):
        raise Unavailable("this libvpx's encoder configuration has a layout this module does not know")
    image = _Image()
    buffer = (c.c_uint8 * (66 * 34 * 2))()
    if not lib.vpx_img_wrap(c.byref(image), _I420, 66, 34, 1, buffer) or (image.d_w, image.d_h) != (66, 34) \
            or image.x_chroma_shift != 1 or image.planes[0] != c.addressof(buffer) or image.stride[0] != 66:
        raise Unavailable("this libvpx's image has a layout this module does not know")
    return lib, encoder, decoder


def _wrap(planes: np.ndarray, size: tuple[int, int]) -> _Image:
    """A vpx_image_t over ``planes`` (I420 as frame_video.to_yuv makes them, kept alive by the caller)."""
    lib = _library()[0]
    image = _Image()
    lib.vpx_img_wrap(ctypes.byref(image), _I420, size[0], size[1], 1, planes.ctypes.data)
    return image


def _planes(image_address: int) -> np.ndarray:
    """The I420 planes of a vpx_image_t libvpx handed out, copied, as frame_video.from_yuv reads them."""
    image = _Image.from_address(image_address)
    w, h = image.d_w, image.d_h
    out = []
    for plane, (pw, ph) in enumerate(((w, h), ((w + 1) // 2, (h + 1) // 2), ((w + 1) // 2, (h + 1) // 2))):
        rows = np.ctypeslib.as_array(ctypes.cast(image.planes[plane], ctypes.POINTER(ctypes.c_uint8)),
                                     shape=(ph, image.stride[plane]))
        out.append(rows[:, :pw].ravel())
    return np.concatenate(out).reshape(-1, w)


class _Codec:
    """A libvpx codec context, destroyed once (by :meth:`close` or when let go)."""

    def __init__(self) -> None:
        self._context = (ctypes.c_uint8 * 1024)()  # vpx_codec_ctx_t, with room to spare
        self._open = False

    def _set_reference(self, slot: int, planes: np.ndarray, size: tuple[int, int]) -> bool:
        reference = _Reference(slot, _wrap(planes, size))
        return _library()[0].vpx_codec_control_(self._context, _SET_REFERENCE, ctypes.byref(reference)) == 0

    def close(self) -> None:
        if self._open:
            self._open = False
            _library()[0].vpx_codec_destroy(self._context)

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001 - the library may be gone at the interpreter's exit
            pass


class Encoder(_Codec):
    """VP9 in real time at ``bitrate`` bit/s over ``fps`` frames a second, of (w, h) ``size`` (multiples
    of 8, :func:`frame_video.video_size`)."""

    def __init__(self, size: tuple[int, int], bitrate: float, fps: float) -> None:
        lib, interface, _ = _library()
        config = (ctypes.c_uint32 * 256)()
        lib.vpx_codec_enc_config_default(interface, config, 0)
        rate = max(1, round(_CLOCK * bitrate / 1000))
        scale = round(fps * 1000)  # the timebase: 1000 / (fps * 1000 * _CLOCK) s
        for name, value in (("threads", 1), ("w", size[0]), ("h", size[1]), ("lag", 0), ("end_usage", 1),
                            ("bitrate", rate), ("finest", _FINEST), ("coarsest", _COARSEST),
                            ("buffer", _BUFFER_MS // _CLOCK), ("buffer_start", _BUFFER_START_MS // _CLOCK),
                            ("buffer_aim", _BUFFER_AIM_MS // _CLOCK), ("key_mode", 0)):
            config[_CONFIG[name][0]] = value
        config[7], config[8] = 1000, scale * _CLOCK
        super().__init__()
        if lib.vpx_codec_enc_init_ver(self._context, interface, config, 0, _ENCODER_ABI) != 0:
            raise Unavailable("libvpx's VP9 encoder did not open")
        self._open = True  # destroyed from here on, if the speed is refused too
        speed = SLOW if size[0] * size[1] <= SLOW_PIXELS else FAST
        if lib.vpx_codec_control_(self._context, _CPU_USED, ctypes.c_int(speed)) != 0:
            raise Unavailable("libvpx's VP9 encoder refused its speed")
        self.size, self._count, self._droppable = size, 0, False

    def set_reference(self, slot: int, planes: np.ndarray) -> None:
        """Puts ``planes`` (I420 of the encoder's size) into reference ``slot`` (LAST, GOLDEN, ALTREF)."""
        if not self._set_reference(slot, planes, self.size):
            raise RuntimeError("libvpx refused a reference")

    def encode(self, planes: np.ndarray, key: bool = False, keep_golden: bool = False,
               droppable: bool = False) -> bytes:
        """The coded frame of ``planes`` (I420), a key if asked; ``keep_golden``: the golden slot is
        not replaced by this frame. ``droppable``: an inter frame that would take libvpx's buffer
        below empty is dropped once coded (b""; the references and contexts as before it, the next frame
        coded at the coarsest quantiser)."""
        lib = _library()[0]
        image = _wrap(np.ascontiguousarray(planes), self.size)
        if droppable != self._droppable:
            if lib.vpx_codec_control_(self._context, _DROP, ctypes.c_uint(droppable)) != 0:
                raise RuntimeError("libvpx refused to drop frames")
            self._droppable = droppable
        flags = (_FORCE_KEY if key else 0) | (_KEEP_GOLDEN if keep_golden else 0)
        if lib.vpx_codec_encode(self._context, ctypes.byref(image), self._count, 1, flags, _REALTIME) != 0:
            raise RuntimeError("libvpx's VP9 encoder failed")
        self._count += 1
        out, iterator = b"", ctypes.c_void_p(None)
        while packet := lib.vpx_codec_get_cx_data(self._context, ctypes.byref(iterator)):
            buffer = ctypes.c_void_p.from_address(packet + 8).value  # VPX_CODEC_CX_FRAME_PKT: buf, sz
            if ctypes.c_int.from_address(packet).value == 0 and buffer:
                out += ctypes.string_at(buffer, ctypes.c_size_t.from_address(packet + 16).value)
        return out


class Decoder(_Codec):
    """VP9 frames of at most ``largest`` (w, h), each checked before libvpx sees it (:func:`frame_size`)."""

    def __init__(self, largest: tuple[int, int]) -> None:
        lib, _, interface = _library()
        super().__init__()
        if lib.vpx_codec_dec_init_ver(self._context, interface, None, 0, _DECODER_ABI) != 0:
            raise Unavailable("libvpx's VP9 decoder did not open")
        self.largest, self._open = largest, True
        self.size: tuple[int, int] | None = None  # the last key's

    def set_reference(self, slot: int, planes: np.ndarray) -> bool:
        """Puts ``planes`` (I420 of the frames' size) into reference ``slot``; False if refused."""
        return self.size is not None and self._set_reference(slot, planes, self.size)

    def decode(self, data: bytes) -> np.ndarray | None:
        """The I420 planes of one coded frame; None if it is not one VP9 frame within ``largest``
        (and of the last key's size after it), or does not decode."""
        size = frame_size(data)
        known = self.size if size == (0, 0) else size  # (0, 0): a reference's, the last key's
        if known is None or known[0] > self.largest[0] or known[1] > self.largest[1] or \
                (self.size is not None and known != self.size):
            return None
        lib = _library()[0]
        if lib.vpx_codec_decode(self._context, data, len(data), None, 0) != 0:
            return None
        iterator, frame, count = ctypes.c_void_p(None), None, 0
        while image := lib.vpx_codec_get_frame(self._context, ctypes.byref(iterator)):
            frame, count = _planes(image), count + 1
        if count != 1 or frame is None:
            return None
        self.size = (frame.shape[1], frame.shape[0] * 2 // 3)
        return frame


class _Bits:
    def __init__(self, data: bytes) -> None:
        self._data, self._at = data, 0

    def read(self, count: int) -> int:
        if self._at + count > 8 * len(self._data):
            raise ValueError("the frame's header ends too soon")
        value = 0
        for _ in range(count):
            value = value << 1 | (self._data[self._at >> 3] >> (7 - (self._at & 7))) & 1
            self._at += 1
        return value


def frame_size(data: bytes) -> tuple[int, int] | None:
    """The (w, h) one VP9 frame (``data``, no superframe) declares in its uncompressed header, (0, 0)
    if it takes a reference's size; None if it is not a shown VP9 frame of 8-bit 4:2:0 (all the layer
    sends). Read before decoding, so that a hostile frame's size is refused before libvpx allocates
    for it."""
    if not data or data[-1] & 0xE0 == 0xC0:  # empty, or a superframe index
        return None
    bits = _Bits(data)
    try:
        if bits.read(2) != 2 or bits.read(2) != 0 or bits.read(1):  # frame marker, profile 0, not a shown copy
            return None
        key, shown, resilient = bits.read(1) == 0, bits.read(1), bits.read(1)
        if not shown:
            return None
        if key:
            if bits.read(24) != 0x498342 or bits.read(3) == 7:  # sync code; a colour space (not RGB)
                return None
            bits.read(1)  # colour range
        else:
            if not resilient:
                bits.read(2)  # reset_frame_context
            bits.read(8)  # refresh_frame_flags
            for _ in range(3):
                bits.read(4)  # ref_frame_idx, sign bias
            for _ in range(3):
                if bits.read(1):  # found_ref: a reference's size
                    return 0, 0
        return bits.read(16) + 1, bits.read(16) + 1
    except ValueError:
        return None
