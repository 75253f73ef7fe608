"""Whether the link loses datagrams now, from the receiver's loss reports (protocol/report.py).

Over UDP fd-send carries each frames packet again in the three datagrams after it and sends one
frame a datagram (sender.config.DATAGRAM_FRAMES), so that bursts of lost datagrams cost few frames:
about five times the bits of the same stream to a file (docs/bitstream.md). On a link that loses
nothing that is waste. While the receiver's reports say that no datagram was lost over the last
CLEAN datagrams (AFTER_LOSS once one was: a link that lost once loses again, and at 1 % random loss,
a datagram every 4 s, each loss while lean would cost frames), fd-send sends no copies and two
frames a datagram; the first report of a loss, or QUIET seconds without a report (the way back
failed, or the receiver does not report), brings the copies back. Keyframes keep their schedule
either way: a datagram lost while lean costs the frames up to the next one (at most 0.24 s), and
the report of it, within REPORT_EVERY, ends the lean spell.
"""

import time
from collections.abc import Callable

from facedeform.protocol.report import REPORT_EVERY, Report

CLEAN = 25  # datagrams reported without a loss before the copies stop, while none was lost (a second)
AFTER_LOSS = 500  # the same once a loss was reported (20 s)
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

    def hear(self, report: Report | None) -> None:
        if report is None:
            return
        if report.lost_since(self._last or _START):  # the first report counts from the call's start
            self._clean, self._clean_from = AFTER_LOSS, report
        elif self._clean_from is None:
            self._clean_from = _START
        self._last, self._heard = report, self._clock()

    @property
    def lean(self) -> bool:
        last, start = self._last, self._clean_from
        return (last is not None and start is not None and self._clock() - self._heard <= QUIET
                and last.datagrams_since(start) >= self._clean)
