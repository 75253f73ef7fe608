"""Where packets go: a file or stdout (byte stream), a TCP connection, or UDP datagrams.

A sink takes the packets of one step of the encoder (``protocol.stream.PacketEncoder``
returns lists of packets): byte-stream sinks write them with their sync bytes,
the UDP sink sends one packet per datagram.
"""

import socket
import sys
import time
from urllib.parse import urlsplit

from facedeform.common.errors import InputError
from facedeform.protocol.report import SIZE, Report, parse_report
from facedeform.protocol.stream import frame_bytes

CONNECT_TIMEOUT = 5.0  # seconds for one attempt to connect
CONNECT_WAIT = 5.0  # seconds a TCP sender keeps trying while no receiver listens yet


class ByteSink:
    """A binary file-like object (a file, stdout, a TCP socket's file); ``sealed``: the packets are."""

    def __init__(self, out, closes: bool = True, sealed: bool = False) -> None:
        self._out, self._closes, self._sealed = out, closes, sealed

    def write(self, packets: list[bytes]) -> None:
        if packets:
            self._out.write(frame_bytes(packets, self._sealed))
            self._out.flush()

    def close(self) -> None:
        if self._closes:
            self._out.close()


class DatagramSink:
    """One UDP datagram per packet to ``address`` (host, port); :meth:`report` reads what the receiver
    reports back (protocol/report.py) to the same socket."""

    def __init__(self, address: tuple[str, int]) -> None:
        self._sock = socket.socket(_family(address), socket.SOCK_DGRAM)
        self._address = address

    def write(self, packets: list[bytes]) -> None:
        for packet in packets:
            self._sock.sendto(packet, self._address)

    def report(self) -> Report | None:
        """The newest report the receiver sent back since the last call (from the port the stream goes
        to), None if none came; anything else on the socket is dropped."""
        newest = None
        while True:
            try:
                data, peer = self._sock.recvfrom(SIZE + 1, socket.MSG_DONTWAIT)
            except OSError:  # nothing waiting (or an ICMP error: no receiver listens yet)
                return newest
            if peer[1] == self._address[1]:
                newest = parse_report(data) or newest

    def close(self) -> None:
        self._sock.close()


def _family(address: tuple[str, int]) -> int:
    return socket.AF_INET6 if ":" in address[0] else socket.AF_INET


def _address(url: str) -> tuple[str, int]:
    parts = urlsplit(url)
    try:
        port = parts.port
    except ValueError:
        port = None
    if not parts.hostname or port is None:
        raise InputError(f"{url}: expected {parts.scheme}://HOST:PORT")
    if not 1 <= port <= 65535:
        raise InputError(f"{url}: the port must be 1 to 65535")
    try:
        socket.getaddrinfo(parts.hostname, port)
    except OSError as exc:
        raise InputError(f"{url}: unknown host ({exc.strerror or exc})") from None
    return parts.hostname, port


def check_destination(output: str) -> None:
    """Refuses, before any work, a udp:// or tcp:// destination that cannot be one (bad port, unknown
    host); whether a TCP receiver listens is known only when the stream starts."""
    if output.startswith(("udp://", "tcp://")):
        _address(output)


def _connect(url: str, address: tuple[str, int]) -> socket.socket:
    """A TCP connection to ``address``, tried again while it is refused (the receiver may start a
    moment after the sender) for :data:`CONNECT_WAIT` seconds."""
    deadline = time.monotonic() + CONNECT_WAIT
    while True:
        try:
            return socket.create_connection(address, timeout=CONNECT_TIMEOUT)
        except ConnectionRefusedError:
            if time.monotonic() >= deadline:
                raise InputError(f"{url}: cannot connect: nobody is listening (tried for {CONNECT_WAIT:g} s; "
                                 "start fd-recv --listen first)") from None
            time.sleep(0.2)
        except OSError as exc:
            raise InputError(f"{url}: cannot connect ({exc.strerror or exc})") from None


def open_sink(output: str, sealed: bool = False):
    """``-`` (stdout), ``udp://HOST:PORT``, ``tcp://HOST:PORT`` or a file path; ``sealed``: the packets are."""
    if output == "-":
        if sys.stdout.isatty():
            raise InputError("refusing to write a binary stream to a terminal: pipe it (| fd-recv) or use -o FILE")
        return ByteSink(sys.stdout.buffer, closes=False, sealed=sealed)
    if output.startswith("udp://"):
        return DatagramSink(_address(output))
    if output.startswith("tcp://"):
        sock = _connect(output, _address(output))
        sock.settimeout(None)
        out = sock.makefile("wb")
        sock.close()  # the connection lives on in ``out`` until it is closed
        return ByteSink(out, sealed=sealed)
    try:
        return ByteSink(open(output, "wb"), sealed=sealed)
    except OSError as exc:
        raise InputError(f"{output}: cannot write ({exc.strerror})") from None
