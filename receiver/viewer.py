"""fd-recv --serve: the live video in any browser, with the call's statistics beside it.

A sink like receiver.output's writers. The page (``/``) shows ``/stream.mjpg``,
the frames as JPEG over HTTP (``multipart/x-mixed-replace``, which every
browser plays in an ``<img>``), and polls ``/stats.json``. Only the latest
frame is kept: a slow browser skips frames instead of queueing them. It needs
no GUI, so it works with the headless OpenCV the project depends on, where
no window could open (fd-recv has no --show for that reason).
"""

import json
import socket
import sys
import threading
import time
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import cv2
import numpy as np

from facedeform.common.errors import InputError

DEFAULT_HOST = "127.0.0.1"  # serving every interface is a choice the user makes by name
BOUNDARY = "fdframe"
JPEG_QUALITY = 85
#: Seconds after which a stream sends its latest frame again when no new one came: a stalled call
#: keeps its picture in browsers that draw a part once the next begins, and a browser that left is noticed.
REPEAT = 1.0
#: Browsers served at once (more are closed at once) and seconds a connection may stay silent
#: (a request not sent, a stream not read) before it is closed: a slow or half-open client costs
#: a thread for at most this long, and a flood of them no more than this many threads.
MAX_CLIENTS, IDLE = 16, 10.0

PAGE = """<!doctype html>
<html><head><meta charset="utf-8"><title>fd-recv</title>
<style>
body { margin: 0; background: #111; color: #ddd; font: 14px sans-serif; display: flex; gap: 16px; padding: 16px; }
img { background: #000; max-width: 75vw; max-height: 90vh; }
th { text-align: left; font-weight: normal; color: #999; padding-right: 12px; }
</style></head>
<body><img src="/stream.mjpg" alt="the call's video">
<table id="stats"><tr><th>waiting for the stream</th></tr></table>
<script>
const rows = [["frames", "frames"], ["concealed", "concealed"], ["damage reports", "damage_reports"],
              ["picture layer lost", "picture_lost"],
              ["kbit/s", "kbit_per_s"], ["frame rate", "fps"], ["face", "face"],
              ["latency, median ms", s => s.latency_ms && s.latency_ms.median]];
async function poll() {
  try {
    const s = await (await fetch("/stats.json", {cache: "no-store"})).json();
    if (s.frames !== undefined) {
      document.getElementById("stats").innerHTML = rows.map(([label, key]) => {
        const v = typeof key === "function" ? key(s) : s[key];
        return `<tr><th>${label}</th><td>${v === null || v === undefined ? "-" : v}</td></tr>`;
      }).join("");
    }
  } catch (e) {}
  setTimeout(poll, 1000);
}
poll();
</script></body></html>
"""


def parse_serve(text: str) -> tuple[str, int]:
    """``HOST:PORT``, ``:PORT`` (HOST 127.0.0.1) or ``[::1]:PORT`` -> (host, port); port 0: any free one."""
    host, colon, port = text.rpartition(":")
    host = host.strip("[]") or DEFAULT_HOST
    if not colon or not port.isdigit() or int(port) > 65535:
        raise InputError(f"--serve {text}: expected HOST:PORT or :PORT, e.g. --serve 127.0.0.1:8080")
    return host, int(port)


class Viewer:
    """Serves the frames written to it (``write((H, W, 3) uint8 RGB)``) at ``url`` until :meth:`close`.

    address: as :func:`parse_serve` reads it; ``stats``: a function returning
    the dict /stats.json shows (set it once the call's session exists).
    """

    def __init__(self, address: str) -> None:
        host, port = parse_serve(address)
        self.stats: Callable[[], dict] = dict
        self._ready = threading.Condition()
        self._frame: np.ndarray | None = None
        self._seq = 0  # frames written so far
        self._jpeg: tuple[int, bytes] = (0, b"")  # the latest frame encoded, and its number
        self._closed = False
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        server = type("Server", (_BoundedServer,), {"address_family": family})
        try:
            self._server = server((host, port), _handler(self))
        except OSError as exc:
            raise InputError(f"cannot serve on {host}:{port} ({exc.strerror or exc})") from None
        bound = self._server.server_address
        self.url = f"http://{f'[{host}]' if ':' in host else host}:{bound[1]}/"
        self._thread = threading.Thread(target=self._server.serve_forever, args=(0.1,), name="fd-recv viewer",
                                        daemon=True)  # polls for close() 10 times a second
        self._thread.start()

    def write(self, rgb: np.ndarray) -> None:
        with self._ready:
            self._frame = rgb.copy()  # the renderer may draw the next frame into the same buffer
            self._seq += 1
            self._ready.notify_all()

    def next_jpeg(self, after: int) -> tuple[int, bytes] | None:
        """(number, JPEG bytes) of the latest frame once one newer than ``after`` is written, or
        after :data:`REPEAT` seconds whatever it is; None when the viewer closes first. Each frame
        is encoded once however many browsers watch."""
        with self._ready:
            self._ready.wait_for(lambda: self._seq > after or self._closed, REPEAT)
            self._ready.wait_for(lambda: self._seq or self._closed)  # nothing to repeat before the first frame
            if self._closed:
                return None
            seq, frame = self._seq, self._frame
            if self._jpeg[0] == seq or frame is None:
                return self._jpeg
        _, data = cv2.imencode(".jpg", cv2.cvtColor(frame, cv2.COLOR_RGB2BGR),
                               [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        self._jpeg = (seq, data.tobytes())
        return self._jpeg

    def close(self) -> None:
        with self._ready:
            if self._closed:
                return
            self._closed = True
            self._ready.notify_all()
        self._server.shutdown()
        self._server.server_close()


def live_stats(session, source, started: float) -> Callable[[], dict]:
    """What /stats.json shows of a call: ``session.stats`` (receiver.session) and the call's rate
    so far in kbit/s: the bytes of ``source`` since its first frame arrived (the header and an
    in-band face model before it are one-off, not rate), at the stream's frame rate."""
    def stats() -> dict:
        s = session.stats(time.perf_counter() - started)
        after = source.consumed - session.bytes_before_frames
        s["kbit_per_s"] = round(8e-3 * after * s["fps"] / s["frames"], 2) if s["frames"] else None
        return s

    return stats


class _BoundedServer(ThreadingHTTPServer):
    """A thread per browser, at most MAX_CLIENTS at once; a client that fails or leaves is no
    traceback on fd-recv's stderr."""

    daemon_threads = True
    #: Connections the kernel queues for accept: room for a flood, so that the ones past MAX_CLIENTS are
    #: closed at once instead of waiting out the kernel's retries of a full queue.
    request_queue_size = 4 * MAX_CLIENTS

    def __init__(self, *args, **kwargs) -> None:
        self._slots = threading.BoundedSemaphore(MAX_CLIENTS)
        super().__init__(*args, **kwargs)

    def process_request(self, request, client_address) -> None:
        if not self._slots.acquire(blocking=False):
            self.shutdown_request(request)
            return
        try:
            super().process_request(request, client_address)
        except BaseException:
            self._slots.release()
            raise

    def process_request_thread(self, request, client_address) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._slots.release()

    def handle_error(self, request, client_address) -> None:
        if not isinstance(sys.exc_info()[1], OSError):  # a browser that left or went silent is not news
            super().handle_error(request, client_address)


def _handler(viewer: Viewer) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        timeout = IDLE  # on every read and write of the connection

        def do_GET(self) -> None:
            path = self.path.split("?")[0]
            if path == "/":
                self._send("text/html; charset=utf-8", PAGE.encode())
            elif path == "/stats.json":
                self._send("application/json", json.dumps(viewer.stats()).encode())
            elif path == "/stream.mjpg":
                self._stream()
            else:
                self.send_error(404)

        def _send(self, kind: str, body: bytes) -> None:
            self.send_response(200)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(body)

        def _stream(self) -> None:
            self.send_response(200)
            self.send_header("Content-Type", f"multipart/x-mixed-replace; boundary={BOUNDARY}")
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            seq = 0
            try:
                self.wfile.write(f"--{BOUNDARY}\r\n".encode())
                while (latest := viewer.next_jpeg(seq)) is not None:
                    seq, jpeg = latest  # each part ends with the next boundary: browsers draw it at once
                    self.wfile.write(f"Content-Type: image/jpeg\r\nContent-Length: {len(jpeg)}\r\n\r\n".encode()
                                     + jpeg + f"\r\n--{BOUNDARY}\r\n".encode())
                    self.wfile.flush()
            except OSError:  # the browser left, or stopped reading for IDLE seconds
                pass

        def log_message(self, format, *args) -> None:  # noqa: A002 (the base class's name)
            """Quiet: fd-recv's stderr is for its own lines."""

    return Handler
