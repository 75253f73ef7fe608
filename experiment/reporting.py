"""fd-recv's end of a UDP call, simulated in process for the benchmarks: its datagram decoder and its
loss reports, without a socket, so that a call's timing is the frames' and not the machine's."""

from facedeform.protocol.report import REPORT_EVERY, Report
from facedeform.protocol.stream import DatagramDecoder
from facedeform.sender.link import LinkWatch


class ReportingReceiver:
    """Decodes each datagram that arrives (:meth:`receive`) and becomes ``session``'s feedback: a report
    every REPORT_EVERY seconds of the call (``session.frame_count`` at ``fps``) once it holds the
    header, as fd-recv sends them (receiver/transport.py); none where ``reports`` is False. The session's
    link watch then keeps the call's time too, not the machine's: the same call whatever its load."""

    def __init__(self, session, fps: float, reports: bool = True) -> None:
        self.decoder = DatagramDecoder()
        self._session, self._fps, self._reports = session, fps, reports
        self._heard, self._last = 0, -REPORT_EVERY
        session.feedback = self.feedback
        session.link = LinkWatch(self.now)

    def now(self) -> float:
        """Seconds of the call so far."""
        return self._session.frame_count / self._fps

    def receive(self, datagram: bytes) -> list:
        self._heard += 1
        return self.decoder.receive(datagram)

    def feedback(self) -> Report | None:
        now = self.now()
        if not self._reports or self.decoder.header is None or now - self._last < REPORT_EVERY:
            return None
        self._last = now
        stats = self.decoder.stats
        return Report(self._heard, stats.repaired, stats.concealed, self.decoder.model_missing, stats.layer_lost)
