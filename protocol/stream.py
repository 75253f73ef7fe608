"""Stream format version 1: a msgpack header, one packet per frame, an end mark.

No I/O here: :func:`encode_header`, :func:`encode_frame` and :func:`encode_end`
return bytes, and :class:`StreamDecoder` takes bytes in any chunking and
returns events. Pipes, files and sockets belong to the command-line tools.

Layout (each item one msgpack object):

- header: ``{"fd": "fdcodec", "v": 1, "fps": float, "names": [str], "steps": [float], "face": str, "f3_with_jaw": bool}``
- frame:  ``[seq, flags, [int, ...]]``, one integer per name (value = int * step)
- end:    ``{"end": frames}``
"""

from dataclasses import dataclass

import msgpack
import numpy as np

from codec.errors import BitstreamError
from protocol.quantise import dequantise, quantise

MAGIC = "fdcodec"
VERSION = 1
FLAG_FACE = 1  # the sender saw a face in this frame
_MAX_OBJECT = 1 << 20  # no valid object comes near this size


@dataclass(frozen=True)
class Header:
    fps: float
    names: tuple[str, ...]
    steps: np.ndarray  # (k,) float64
    face_id: str
    f3_with_jaw: bool = False


@dataclass(frozen=True)
class Frame:
    seq: int
    params: np.ndarray  # (k,) float64, dequantised
    face_seen: bool
    concealed: bool = False  # not received: the decoder repeated the last frame


@dataclass(frozen=True)
class End:
    frames: int


def encode_header(header: Header) -> bytes:
    return msgpack.packb({
        "fd": MAGIC, "v": VERSION, "fps": float(header.fps), "names": list(header.names),
        "steps": [float(s) for s in header.steps], "face": header.face_id,
        "f3_with_jaw": bool(header.f3_with_jaw),
    })


def encode_frame(header: Header, seq: int, params: np.ndarray, face_seen: bool) -> bytes:
    """One frame's packet; ``params`` (k,) float in ``header.names`` order."""
    return msgpack.packb([seq, FLAG_FACE if face_seen else 0, quantise(params, header.steps)])


def encode_end(frames: int) -> bytes:
    return msgpack.packb({"end": frames})


class StreamDecoder:
    """Incremental decoder: ``feed`` bytes, get :class:`Header`, :class:`Frame` and :class:`End` events.

    A missing sequence number becomes a concealed frame (the last frame repeated),
    so the receiver still outputs one frame per frame sent.
    """

    def __init__(self) -> None:
        self._unpacker = msgpack.Unpacker(max_buffer_size=_MAX_OBJECT, strict_map_key=True)
        self.header: Header | None = None
        self._next_seq = 0
        self._last: np.ndarray | None = None
        self._ended = False
        self._seen_bytes = False

    def feed(self, data: bytes) -> list:
        """Events completed by ``data``; raises :class:`BitstreamError` on anything not ours."""
        self._seen_bytes = self._seen_bytes or bool(data)
        try:
            self._unpacker.feed(data)
            objects = list(self._unpacker)
        except Exception as exc:  # msgpack's own errors: garbage where a packet should be
            raise BitstreamError(f"corrupted stream ({type(exc).__name__})") from None
        events = []
        for obj in objects:
            events.extend(self._event(obj))
        return events

    def close(self) -> None:
        """Call at the end of input: raises if the stream stopped short."""
        if self.header is None:
            raise BitstreamError("empty input: no fd stream" if not self._seen_bytes
                                 else "input is not an fd stream (no complete header)")
        if not self._ended:
            raise BitstreamError(f"truncated stream: ended after {self._next_seq} frames without its end mark")

    def _event(self, obj) -> list:
        if self._ended:
            raise BitstreamError("data after the end of the stream")
        if self.header is None:
            self.header = _parse_header(obj)
            return [self.header]
        if isinstance(obj, dict):
            frames = obj.get("end")
            if not isinstance(frames, int) or len(obj) != 1:
                raise BitstreamError("corrupted stream: unexpected map where a packet should be")
            self._ended = True
            return [End(frames)]
        return self._frames(obj)

    def _frames(self, obj) -> list:
        k = len(self.header.names)
        if not (isinstance(obj, list) and len(obj) == 3 and isinstance(obj[0], int)
                and isinstance(obj[1], int) and isinstance(obj[2], list) and len(obj[2]) == k
                and all(isinstance(q, int) for q in obj[2])):
            raise BitstreamError("corrupted stream: malformed frame packet")
        seq, flags, indices = obj
        if seq < self._next_seq:
            raise BitstreamError(f"corrupted stream: frame {seq} after frame {self._next_seq - 1}")
        events = []
        if self._last is not None:
            events = [Frame(s, self._last, False, concealed=True) for s in range(self._next_seq, seq)]
        self._last = dequantise(indices, self.header.steps)
        events.append(Frame(seq, self._last, bool(flags & FLAG_FACE)))
        self._next_seq = seq + 1
        return events


def _parse_header(obj) -> Header:
    if not (isinstance(obj, dict) and obj.get("fd") == MAGIC):
        raise BitstreamError("input is not an fd stream (no fdcodec header)")
    if obj.get("v") != VERSION:
        raise BitstreamError(f"unsupported stream version {obj.get('v')!r} (this decoder reads {VERSION})")
    try:
        names = tuple(str(n) for n in obj["names"])
        steps = np.asarray(obj["steps"], dtype=np.float64)
        header = Header(float(obj["fps"]), names, steps, str(obj["face"]), bool(obj.get("f3_with_jaw", False)))
    except (KeyError, TypeError, ValueError):
        raise BitstreamError("corrupted stream header") from None
    if steps.shape != (len(names),) or not np.all(steps > 0) or not 0 < header.fps <= 1000:
        raise BitstreamError("corrupted stream header")
    return header
