"""facedeform: a model-based video codec for talking faces.

The library API is three verbs over iterators (``facedeform.api``)::

    face = facedeform.enroll("me.mp4")                  # once, before the call
    stream = b"".join(facedeform.encode("talk.mp4", face))
    for frame in facedeform.decode(stream, face):       # (H, W, 3) uint8 RGB
        ...

The command-line tools (fd-send, fd-recv, fd-enroll, ...) are thin shells over
the same code. The packages below this one follow the data:
``sender`` (frames -> landmarks -> parameters), ``protocol`` (parameters <->
bits), ``codec`` (face model, deformation, rendering: parameters -> pixels),
``receiver`` (bits -> pixels), ``experiment`` (comparisons with other codecs)
and ``common`` (errors, keys, command-line plumbing).
"""

from facedeform.api import Face, decode, encode, enroll

__all__ = ["Face", "decode", "encode", "enroll"]
__version__ = "0.1.0"
