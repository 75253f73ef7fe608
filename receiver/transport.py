"""Where the stream comes from: a file or stdin, a TCP connection, or UDP datagrams.

Every source yields ``(events, arrived)`` batches: the decoder's events for one
chunk or datagram and the ``time.perf_counter()`` at which it arrived, so the
session can measure each frame's latency from arrival to output. A socket
source ends when the stream's end mark arrives, when the peer closes (TCP), or
after ``idle`` seconds without data once the stream has started (a UDP end
mark can be lost, and a sender can vanish). With a key every source decodes
through ``protocol.secure_stream`` instead: only authentic packets count.
"""

import os
import queue
import selectors
import socket
import stat
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import urlsplit

from facedeform.common.errors import BitstreamError, InputError
from facedeform.protocol.framing import MAX_BODY, SYNC
from facedeform.protocol.header import Header, encode_header, parse_header
from facedeform.protocol.report import REPORT_EVERY, Report, encode_report
from facedeform.protocol.secure import MAGIC
from facedeform.protocol.secure_stream import SecureDatagramDecoder, SecureStreamDecoder
from facedeform.protocol.stream import Damage, DatagramDecoder, StreamDecoder

CHUNK = 1 << 10  # bytes read at a time: a batch of events (a few hundred frames) stays small however long the file
DEFAULT_HOST = "127.0.0.1"  # listening on every interface is a choice the user makes by name
RCVBUF = 4 << 20  # bytes of UDP socket buffer asked for (Linux caps it at net.core.rmem_max)
QUEUE = 1024  # batches of decoded events waiting for the renderer
_POLL = 0.1  # seconds: how often the reader looks up from the socket to see whether to stop
HEADER_SUFFIX = ".fdheader"
#: TCP: connections heard at once while waiting for the sender, and seconds each may stay silent.
MAX_CANDIDATES, FIRST_BYTES = 8, 5.0
MAX_HEADERS = 1000  # header files read from a --headers directory


class ByteSource:
    """A byte stream (file, stdin, accepted TCP connection) through a :class:`StreamDecoder`.

    read: returns up to n bytes, b"" at the end; raises TimeoutError when idle
    (sockets). ``size``: total bytes if known (a file), for progress; ``key``: the stream is sealed.
    """

    def __init__(self, read, size: int | None = None, closing=None, key: bytes | None = None) -> None:
        self.decoder = StreamDecoder() if key is None else SecureStreamDecoder(key)
        self.size, self.consumed = size, 0
        self.timed_out = False
        self._read, self._closing = read, closing
        self._head = b""  # the first bytes, to tell a sealed stream from junk

    def batches(self) -> Iterator[tuple[list, float]]:
        try:
            while not self.decoder.ended:
                try:
                    chunk = self._read(CHUNK)
                except TimeoutError:
                    self.timed_out = True
                    break
                if not chunk:
                    break
                self.consumed += len(chunk)
                self._head = self._head or chunk[:len(MAGIC) + 1]
                yield self.decoder.feed(chunk), time.perf_counter()
            try:
                events = self.decoder.close()
            except BitstreamError:
                if self._head == bytes([SYNC]) + MAGIC and isinstance(self.decoder, StreamDecoder):
                    raise BitstreamError(_SEALED) from None
                raise
            # the end's damage is the truncation, which the session reports itself
            yield [e for e in events if not isinstance(e, Damage)], time.perf_counter()
        finally:
            if self._closing is not None:
                self._closing()

    def no_stream(self) -> str:
        return _no_stream(self.decoder, self._head == bytes([SYNC]) + MAGIC)


def open_file(path: str, stdin, key: bytes | None = None) -> ByteSource:
    """``-`` (the binary ``stdin``) or a stream file."""
    if path == "-":
        return ByteSource(getattr(stdin, "read1", stdin.read), key=key)
    try:
        f = open(path, "rb")
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    return ByteSource(f.read1, os.fstat(f.fileno()).st_size, f.close, key)


class UdpSource:
    """Datagrams on a bound UDP socket through a :class:`DatagramDecoder`, read by a thread of their own.

    Reading never waits on rendering: a reader thread takes each datagram off
    the socket (whose buffer is :data:`RCVBUF`), drops what cannot be ours
    before any decoding work (``DatagramDecoder.could_start``; with a key,
    the envelope's length and the replay window before the tag), decodes the
    rest and queues the events of each (at most :data:`QUEUE` batches; junk
    queues none, and the reader waits only if rendering falls behind the
    real stream). ``headers``: where the headers of earlier calls are kept
    (a receiver restarted mid-call starts at the first keyframe that names one).
    Without a key, and unless ``reports`` is False, it sends a loss report (protocol/report.py) back to
    where the stream comes from every REPORT_EVERY seconds, so that the sender sends its copies only
    while they are needed.
    """

    def __init__(self, sock: socket.socket, idle: float, key: bytes | None = None,
                 headers: "HeaderStore | None" = None, reports: bool = True) -> None:
        known = headers.load() if headers is not None else ()
        self.decoder = DatagramDecoder(known) if key is None else SecureDatagramDecoder(key, known=known)
        self._headers = headers
        self.size, self.consumed = None, 0
        self.timed_out = False
        self._sock, self._idle = sock, idle
        self._sealed = False  # a sealed stream's preamble arrived
        self._reports = reports and key is None
        self._received = 0  # datagrams of the stream
        self._reported = -REPORT_EVERY  # when the last report went
        self._queue: queue.Queue = queue.Queue(QUEUE)
        self._stop = threading.Event()
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF)
        except OSError:  # the kernel's limit stands
            pass

    def batches(self) -> Iterator[tuple[list, float]]:
        reader = threading.Thread(target=self._read, name="fd-recv reader", daemon=True)
        reader.start()
        try:
            while (item := self._queue.get()) is not None:
                if isinstance(item, BaseException):
                    raise item
                yield item
        finally:
            self._stop.set()
            reader.join()
            self._sock.close()

    def _read(self) -> None:
        """The reader thread: datagrams in, batches of events queued, None queued at the end."""
        try:
            self._sock.settimeout(_POLL)
            last = None  # when the last datagram arrived: silence for ``idle`` after it ends the stream
            while not self.decoder.ended and not self._stop.is_set():
                try:
                    data, peer = self._sock.recvfrom(65536)
                except TimeoutError:
                    if last is not None and time.monotonic() - last > self._idle:
                        self.timed_out = True
                        break
                    continue
                arrived, last = time.perf_counter(), time.monotonic()
                self.consumed += len(data)
                self._sealed = self._sealed or data.startswith(MAGIC)
                events = self.decoder.receive(data)
                if events:
                    if self._headers is not None and isinstance(events[0], Header):
                        self._headers.keep(events[0])
                    self._put((events, arrived))
                    self._report(peer)
        except Exception as exc:  # raised again in the consumer's thread
            self._put(exc)
        self._put(None)

    def _report(self, peer) -> None:
        """After a datagram of the stream from ``peer``: a loss report to it, at most every REPORT_EVERY
        seconds once the header is held (a sender that does not read them drops them; one that hears
        none keeps the copies and repeats the header often: what a receiver that joined late needs)."""
        self._received += 1
        now = time.monotonic()
        if not self._reports or self.decoder.header is None or now - self._reported < REPORT_EVERY:
            return
        self._reported = now
        stats = self.decoder.stats
        try:
            self._sock.sendto(encode_report(Report(self._received, stats.repaired, stats.concealed,
                                                   self.decoder.model_missing, stats.layer_lost)), peer)
        except OSError:  # the way back is closed: the sender keeps its copies
            self._reports = False

    def _put(self, item) -> None:
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=_POLL)
                return
            except queue.Full:
                continue

    def no_stream(self) -> str:
        return _no_stream(self.decoder, self._sealed)


class HeaderStore:
    """A directory of stream headers, one file each named by its id (``Header.ident``): a receiver
    that holds a call's header starts at its first keyframe, without waiting for the header to be
    sent again (``protocol.encoder.Datagrams``). Files that are not headers are passed over."""

    def __init__(self, directory: str) -> None:
        self.path = Path(directory)
        if not self.path.is_dir():
            raise InputError(f"--headers {directory}: not a directory")

    def load(self) -> list[Header]:
        """The headers kept here: regular files only (a link, a FIFO or a device planted under a
        header's name is passed over without being followed or opened for long), each read to at
        most one packet's length."""
        headers = []
        for file in sorted(self.path.glob("*" + HEADER_SUFFIX))[:MAX_HEADERS]:
            try:
                fd = os.open(file, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
            except OSError:
                continue
            with os.fdopen(fd, "rb") as f:
                try:
                    if not stat.S_ISREG(os.fstat(fd).st_mode):
                        continue
                    headers.append(parse_header(f.read(MAX_BODY)))
                except (OSError, BitstreamError):
                    continue
        return headers

    def keep(self, header: Header) -> None:
        """Writes the header to a new file and renames it into place: a link planted under its
        name is replaced, never written through."""
        target = self.path / (header.ident.hex() + HEADER_SUFFIX)
        try:
            fd, temporary = tempfile.mkstemp(HEADER_SUFFIX + ".new", dir=self.path)
            with os.fdopen(fd, "wb") as f:
                f.write(encode_header(header))
            os.replace(temporary, target)
        except OSError:  # a receiver shows the call whether or not it can keep the header
            pass


_SEALED = "the stream is sealed (encrypted): give fd-recv --key FILE"


def _after(first: bytes, read):
    """read(n) that returns ``first`` before what ``read`` gives."""
    pending = [first] if first else []

    def chained(n: int) -> bytes:
        return pending.pop() if pending else read(n)

    return chained


def _no_stream(decoder, sealed: bool) -> str:
    """Why no stream could be decoded, as one line for the user."""
    if hasattr(decoder, "no_stream"):
        return decoder.no_stream()
    return _SEALED if sealed else "no fd stream arrived (no valid header)"


def parse_listen(url: str) -> tuple[str, str, int]:
    """``udp://HOST:PORT`` or ``tcp://HOST:PORT`` (HOST may be empty: 127.0.0.1) -> (scheme, host, port)."""
    parts = urlsplit(url)
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme not in ("udp", "tcp") or port is None or parts.path not in ("", "/"):
        raise InputError(f"--listen {url}: expected udp://HOST:PORT or tcp://HOST:PORT")
    return parts.scheme, parts.hostname or DEFAULT_HOST, port


class Listener:
    """A bound socket for ``--listen``; :meth:`source` waits for the stream (blocking)."""

    def __init__(self, url: str, idle: float, key: bytes | None = None, headers: str | None = None,
                 reports: bool = True) -> None:
        self.scheme, host, port = parse_listen(url)
        self._reports = reports
        self._headers = None if headers is None else HeaderStore(headers)
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        kind = socket.SOCK_DGRAM if self.scheme == "udp" else socket.SOCK_STREAM
        self._sock = socket.socket(family, kind)
        self._idle, self._key = idle, key
        try:
            if kind == socket.SOCK_STREAM:  # a port in TIME_WAIT may be reused; one in use still fails
                self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._sock.bind((host, port))
            if kind == socket.SOCK_STREAM:
                self._sock.listen(MAX_CANDIDATES)
        except OSError as exc:
            self._sock.close()
            raise InputError(f"cannot listen on {self.scheme}://{host}:{port} ({exc.strerror or exc})") from None
        bound = self._sock.getsockname()
        self.url = f"{self.scheme}://{f'[{bound[0]}]' if family == socket.AF_INET6 else bound[0]}:{bound[1]}"

    def source(self):
        """UDP: the datagram source at once; TCP: the first connection's bytes, once it is accepted."""
        if self.scheme == "udp":
            return UdpSource(self._sock, self._idle, self._key, self._headers, self._reports)
        try:
            conn, first = self._first_stream()
        finally:
            self._sock.close()
        conn.settimeout(self._idle)
        return ByteSource(_after(first, conn.recv), closing=conn.close, key=self._key)

    def _first_stream(self) -> tuple[socket.socket, bytes]:
        """(the first connection whose first bytes start an fd stream, those bytes). Connections
        are accepted as they come, up to MAX_CANDIDATES at once: one that stays silent for
        FIRST_BYTES seconds, closes, or sends anything else is closed, so that an idle or stray
        client cannot lock the real sender out."""
        candidates: dict[socket.socket, float] = {}  # connection -> when it must have spoken
        with selectors.DefaultSelector() as selector:
            selector.register(self._sock, selectors.EVENT_READ)
            try:
                while True:
                    now = time.monotonic()
                    for conn in [c for c, due in candidates.items() if due <= now]:
                        selector.unregister(conn)
                        conn.close()
                        del candidates[conn]
                    wait = min(candidates.values()) - now if candidates else None
                    for ready, _ in selector.select(wait):
                        if ready.fileobj is self._sock:
                            conn, _ = self._sock.accept()
                            if len(candidates) >= MAX_CANDIDATES:
                                conn.close()
                                continue
                            conn.setblocking(False)
                            selector.register(conn, selectors.EVENT_READ)
                            candidates[conn] = now + FIRST_BYTES
                            continue
                        conn = ready.fileobj  # type: ignore[assignment]
                        selector.unregister(conn)
                        del candidates[conn]
                        try:
                            first = conn.recv(CHUNK)
                        except OSError:
                            first = b""
                        if first[:1] == bytes([SYNC]):
                            conn.setblocking(True)
                            return conn, first
                        conn.close()
            finally:
                for conn in candidates:
                    conn.close()

    def close(self) -> None:
        self._sock.close()
