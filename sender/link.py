"""Whether the link loses datagrams now, from the receiver's loss reports (protocol/report.py).

Over UDP fd-send carries each frames packet again in the three datagrams after it, sends one frame
a datagram (sender.config.DATAGRAM_FRAMES) and a keyframe every 0.24 s, so that bursts of lost
datagrams cost few frames: about five times the bits of the same stream to a file
(docs/bitstream.md). On a link that loses nothing that is waste. From the first report that shows
no loss (AFTER_LOSS clean datagrams once one was: a link that lost once loses again, and at 1 %
random loss, a datagram every 4 s, each loss while lean would cost frames), fd-send sends no copies,
two frames a datagram and a keyframe at every LEAN_KEYS-th of its places; the first report of a
loss, or QUIET seconds without a report (the way back failed, or the receiver does not report),
brings the copies and every keyframe back. A datagram lost while lean costs the frames up to the
next keyframe, and the report of it, within REPORT_EVERY, ends the lean spell. A picture layer
payload lost counts as a loss too (the report's ``layer``): the session then asks the layer's next key.
"""

import time
from collections.abc import Callable

from facedeform.protocol.report import REPORT_EVERY, Report

#: Datagrams reported without a loss before the copies stop, while none was lost: the first report
#: that shows none. (25, a second's, had left a 5-second call's first 1.5 s at the full cost; a loss
#: while lean costs the same few frames once either way, docs/bitstream.md.)
CLEAN = 1
AFTER_LOSS = 500  # the same once a loss was reported (20 s)
#: While lean, a keyframe at every so many of the header's key places (0.24 s apart at fd-send's
#: defaults): a datagram lost then costs at most twice that many places' frames.
LEAN_KEYS = 2
QUIET = 3 * REPORT_EVERY  # seconds without a report after which the copies come back
_START = Report(0, 0, 0)


class LinkWatch:
    """Hears the receiver's reports (:meth:`hear`, with None when none came) and says whether the
    link is clean enough to send lean (:attr:`lean`)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._last: Report | None = None
        self._heard = -float("inf")  # when the last report came
        self._clean_from: Report | None = None  # the report since which none shows a loss
        self._clean = CLEAN  # datagrams they must show without one
        self.lost = False  # the last report heard shows a loss

    def hear(self, report: Report | None) -> None:
        if report is None:
            return
        self.lost = bool(report.lost_since(self._last or _START))  # the first report counts from the call's start
        if self.lost:
            self._clean, self._clean_from = AFTER_LOSS, report
        elif self._clean_from is None:
            self._clean_from = _START
        self._last, self._heard = report, self._clock()

    @property
    def heard(self) -> bool:
        """A report came: the receiver decodes the stream."""
        return self._last is not None

    @property
    def lean(self) -> bool:
        last, start = self._last, self._clean_from
        return (last is not None and start is not None and self._clock() - self._heard <= QUIET
                and last.datagrams_since(start) >= self._clean)
