"""The receiver's loss report: what fd-recv sends back to the sender over UDP, so that the sender
spends its redundancy only while datagrams are being lost (sender/link.py).

One datagram, against the stream's direction, every REPORT_EVERY seconds while the stream comes::

    "FDLR" | version (1 byte) | datagrams received | frames packets repaired | frames concealed

each count a 32-bit big-endian unsigned integer, counted from the call's start (wrapping), so that a
lost report loses nothing: the sender takes the differences between the reports it hears. Repaired:
taken from a later datagram's copies (``protocol.events.Stats.repaired``); concealed: frames the
receiver drew without their data. A report is not authenticated: a forged one can make the sender
send its copies when they are not needed, or drop them on a link that loses (then the next real
report brings them back); fd-send does not read reports on a sealed stream (--key).
"""

import struct
from dataclasses import dataclass

MAGIC = b"FDLR"
VERSION = 1
REPORT_EVERY = 0.5  # seconds: 45 bytes on the wire with IPv4 and UDP, 0.7 kbit/s back
_LAYOUT = struct.Struct(">4sBIII")
SIZE = _LAYOUT.size
_WRAP = 1 << 32


@dataclass(frozen=True)
class Report:
    """A receiver's counts since the call started (modulo 2**32)."""

    datagrams: int
    repaired: int
    concealed: int

    def datagrams_since(self, before: "Report") -> int:
        """Datagrams received between ``before`` and this report."""
        return (self.datagrams - before.datagrams) % _WRAP

    def lost_since(self, before: "Report") -> int:
        """Frames packets repaired and frames concealed between ``before`` and this report."""
        return (self.repaired - before.repaired) % _WRAP + (self.concealed - before.concealed) % _WRAP


def encode_report(report: Report) -> bytes:
    return _LAYOUT.pack(MAGIC, VERSION, report.datagrams % _WRAP, report.repaired % _WRAP,
                        report.concealed % _WRAP)


def parse_report(data: bytes) -> Report | None:
    """The report in ``data``; None if it is not one of this version (anything else on the socket)."""
    if len(data) != SIZE:
        return None
    magic, version, datagrams, repaired, concealed = _LAYOUT.unpack(data)
    if magic != MAGIC or version != VERSION:
        return None
    return Report(datagrams, repaired, concealed)
