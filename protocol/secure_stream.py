"""Sealed streams in, events out: the decoders of protocol/stream.py behind a :class:`SecureOpener`.

Only packets that authenticate reach the packet decoder (the envelope says its
own length, and its tag is checked before a byte inside is decrypted), so
forged, damaged or replayed packets cannot change its state: a flood of junk datagrams is counted
and otherwise ignored, and the real stream's frames come through untouched. On
a byte stream a packet that fails is damage as in the clear format (the decoder
resumes at the next sync byte); a datagram that fails is just dropped, since it
may not be ours at all (a lost packet of ours shows at the next delta's check).
"""

from facedeform.common.errors import BitstreamError
from facedeform.protocol.decoder import MAX_SEEK, ByteStreamDecoder, PacketDecoder, WrapsPacketDecoder
from facedeform.protocol.secure import MAGIC, WINDOW, SecureOpener, SecureSealer, SecureStats, preamble_size


class _Secure(WrapsPacketDecoder):
    def __init__(self, key: bytes, window: int, known=()) -> None:
        self._core = PacketDecoder(known, late_join=True)
        self.opener = SecureOpener(key, window)

    @property
    def security(self) -> SecureStats:
        return self.opener.stats

    def no_stream(self) -> str:
        return self.opener.no_stream()


class SecureDatagramDecoder(_Secure):
    """One sealed packet (or the preamble) per datagram, like :class:`protocol.stream.DatagramDecoder`
    (``known``: the headers it holds)."""

    def __init__(self, key: bytes, window: int = WINDOW, known=()) -> None:
        super().__init__(key, window, known)
        self._received = 0  # bytes of every datagram before this one, junk too: what pays for frames

    def receive(self, data: bytes) -> list:
        events: list = []
        if self.opener.wants_preamble(data):
            self.opener.preamble(data)
        elif data != self.opener.accepted:  # a copy of it is sent again for receivers that join late
            packet = self.opener.open(data)
            events = [] if packet is None else self._core.packet(packet, self._received)
        self._received += len(data)
        return events


class SecureStreamDecoder(_Secure, ByteStreamDecoder):
    """A sealed byte stream in any chunking, like :class:`protocol.stream.StreamDecoder`.

    :meth:`close` raises BitstreamError if no sealed stream for this key was found (a wrong key says so).
    """

    def __init__(self, key: bytes, window: int = WINDOW) -> None:
        ByteStreamDecoder.__init__(self)
        self.opener = SecureOpener(key, window)

    def _no_stream(self) -> str:
        return self.no_stream()

    def _packet_at(self, pos: int, final: bool) -> tuple[list, int] | None:
        buf = self._buf
        preamble = self.opener.wants_preamble(buf[pos + 1:pos + 1 + len(MAGIC)])
        size = self._size(pos + 1, preamble)
        if not final and (size is None or pos + 1 + size > len(buf)):
            return None
        sealed = bytes(buf[pos + 1:pos + 1 + size]) if size else b""
        if preamble:
            if size and self.opener.preamble(sealed):
                return [], 1 + size
            return self._skip(1, ""), 1
        packet = self.opener.open(sealed) if size else None
        if packet is None or not size:
            return self._skip(1, "packet fails authentication"), 1
        return self._core.packet(packet, self._base + pos), 1 + size  # authentic: never resync inside it

    def _size(self, pos: int, preamble: bool) -> int | None:
        """0 when the bytes at ``pos`` cannot start a preamble (or a sealed packet)."""
        buf = self._buf
        if preamble:
            if len(buf) < pos + len(MAGIC) + 1:
                return None if buf[pos:] == MAGIC[:len(buf) - pos] else 0
            return preamble_size(buf[pos + len(MAGIC)]) if buf[pos:pos + len(MAGIC)] == MAGIC else 0
        try:
            return self.opener.size(buf, pos)
        except BitstreamError:
            return 0

    def _skip(self, n: int, reason: str) -> list:
        self._core.stats.skipped_bytes += n
        if self._core.header is None:
            if not self.opener.ready and self._core.stats.skipped_bytes > MAX_SEEK:
                raise BitstreamError(self.no_stream())
            return []
        return self._core.damage(reason)


def seal_stream(sealer: SecureSealer, packets: list[bytes]) -> list[bytes]:
    """A whole stream's packets sealed, the preamble first (tests, files)."""
    return [sealer.preamble()] + sealer.seal_all(packets)
