"""The receiver's loss report: what fd-recv sends back to the sender over UDP, so that the sender
spends its redundancy only while datagrams are being lost (sender/link.py).

One datagram, against the stream's direction, every REPORT_EVERY seconds while the stream comes::

    "FDLR" | version (1 byte) | datagrams received | frames packets repaired | frames concealed | face
           | picture payloads lost

each count a 32-bit big-endian unsigned integer, counted from the call's start (wrapping), so that a
lost report loses nothing: the sender takes the differences between the reports it hears. ``face``
(version 2) is the first byte of the stream's face model the receiver does not hold (the model's size
once it holds it all, or by its id): a paced face goes on from there, and stops once it is whole
(sender/face_pacing.py). ``layer`` (version 3): the picture layer's payloads the receiver found lost
where they were due (``protocol.events.Stats.layer_lost``): they travel in datagrams of their own, whose
loss the frames' counts do not show, and the sender answers one with the layer's next key at once
(sender/link.py). Versions 1 and 2, without them, are still read. Repaired:
taken from a later datagram's copies (``protocol.events.Stats.repaired``); concealed: frames the
receiver drew without their data. A report is not authenticated: a forged one can make the sender
send its copies when they are not needed, or drop them on a link that loses (then the next real
report brings them back); fd-send does not read reports on a sealed stream (--key).
"""

import struct
from dataclasses import dataclass

MAGIC = b"FDLR"
VERSION = 3
REPORT_EVERY = 0.5  # seconds: 53 bytes on the wire with IPv4 and UDP, 0.85 kbit/s back
_LAYOUT = struct.Struct(">4sBIIIII")
_OLDER = (struct.Struct(">4sBIII"), struct.Struct(">4sBIIII"))  # versions 1 (no face) and 2 (no layer)
SIZE = _LAYOUT.size
_WRAP = 1 << 32


@dataclass(frozen=True)
class Report:
    """A receiver's counts since the call started (modulo 2**32)."""

    datagrams: int
    repaired: int
    concealed: int
    face: int | None = None  # the first byte of the face model not held; None: not said (version 1)
    layer: int = 0  # picture layer payloads lost (0 in versions 1 and 2, which do not say)

    def datagrams_since(self, before: "Report") -> int:
        """Datagrams received between ``before`` and this report."""
        return (self.datagrams - before.datagrams) % _WRAP

    def lost_since(self, before: "Report") -> int:
        """Frames packets repaired, frames concealed and picture layer payloads lost between ``before``
        and this report."""
        return sum((now - then) % _WRAP for now, then in ((self.repaired, before.repaired),
                                                         (self.concealed, before.concealed),
                                                         (self.layer, before.layer)))


def encode_report(report: Report) -> bytes:
    return _LAYOUT.pack(MAGIC, VERSION, report.datagrams % _WRAP, report.repaired % _WRAP,
                        report.concealed % _WRAP, min(report.face or 0, _WRAP - 1), report.layer % _WRAP)


def parse_report(data: bytes) -> Report | None:
    """The report in ``data``; None if it is not one of versions 1 to 3 (anything else on the socket)."""
    for version, layout in enumerate((*_OLDER, _LAYOUT), start=1):
        if len(data) == layout.size:
            magic, got, datagrams, repaired, concealed, *rest = layout.unpack(data)
            if magic != MAGIC or got != version:
                return None
            return Report(datagrams, repaired, concealed, rest[0] if rest else None, *rest[1:])
    return None
