"""The receiver's loss report: what fd-recv sends back to the sender over UDP, so that the sender
spends its redundancy only while datagrams are being lost (sender/link.py).

One datagram, against the stream's direction, every REPORT_EVERY seconds while the stream comes::

    "FDLR" | version (1 byte) | datagrams received | frames packets repaired | frames concealed | face

each count a 32-bit big-endian unsigned integer, counted from the call's start (wrapping), so that a
lost report loses nothing: the sender takes the differences between the reports it hears. ``face``
(version 2) is the first byte of the stream's face model the receiver does not hold (the model's size
once it holds it all, or by its id): a paced face goes on from there, and stops once it is whole
(sender/face_pacing.py). Version 1 reports, without it, are still read. Repaired:
taken from a later datagram's copies (``protocol.events.Stats.repaired``); concealed: frames the
receiver drew without their data. A report is not authenticated: a forged one can make the sender
send its copies when they are not needed, or drop them on a link that loses (then the next real
report brings them back); fd-send does not read reports on a sealed stream (--key).
"""

import struct
from dataclasses import dataclass

MAGIC = b"FDLR"
VERSION = 2
REPORT_EVERY = 0.5  # seconds: 49 bytes on the wire with IPv4 and UDP, 0.8 kbit/s back
_LAYOUT = struct.Struct(">4sBIIII")
_FIRST = struct.Struct(">4sBIII")  # version 1: no face
SIZE = _LAYOUT.size
_WRAP = 1 << 32


@dataclass(frozen=True)
class Report:
    """A receiver's counts since the call started (modulo 2**32)."""

    datagrams: int
    repaired: int
    concealed: int
    face: int | None = None  # the first byte of the face model not held; None: not said (version 1)

    def datagrams_since(self, before: "Report") -> int:
        """Datagrams received between ``before`` and this report."""
        return (self.datagrams - before.datagrams) % _WRAP

    def lost_since(self, before: "Report") -> int:
        """Frames packets repaired and frames concealed between ``before`` and this report."""
        return (self.repaired - before.repaired) % _WRAP + (self.concealed - before.concealed) % _WRAP


def encode_report(report: Report) -> bytes:
    return _LAYOUT.pack(MAGIC, VERSION, report.datagrams % _WRAP, report.repaired % _WRAP,
                        report.concealed % _WRAP, min(report.face or 0, _WRAP - 1))


def parse_report(data: bytes) -> Report | None:
    """The report in ``data``; None if it is not one of versions 1 and 2 (anything else on the socket)."""
    for layout, version, ours in ((_LAYOUT, VERSION, True), (_FIRST, 1, False)):
        if len(data) == layout.size:
            magic, got, datagrams, repaired, concealed, *face = layout.unpack(data)
            if magic != MAGIC or got != version:
                return None
            return Report(datagrams, repaired, concealed, face[0] if ours else None)
    return None
