"""Speed and bitrate of the whole chain on a clip (the bundled sample by default).

Prints one Markdown table row per clip, dated, ready for the README:
sender frames/s (decode video + track + estimate + encode), receiver frames/s
(decode stream + deform + render, and with H.264 writing), bits per frame, bit/s.
"""

import datetime
import io
import tempfile
import time
from pathlib import Path

from facedeform.codec.model.face_model import load_base_face
from facedeform.common.cli import ArgumentParser, run_main
from facedeform.protocol.stream import Frame, StreamDecoder
from facedeform.receiver.face_view import FaceView
from facedeform.receiver.output import open_writer
from facedeform.sender.session import SendSession

ROOT = Path(__file__).resolve().parents[1]


def bench(clip: Path, size: int) -> str:
    session = SendSession(str(clip))
    started = time.perf_counter()
    data = b"".join(session.stream())
    send_s = time.perf_counter() - started
    n = session.frame_count

    decoder = StreamDecoder()
    events = decoder.feed(data) + decoder.close()
    view = FaceView(events[0], load_base_face(), (size, size))
    frames = [e for e in events if isinstance(e, Frame)]
    view.render(frames[0].params)  # compile and warm up outside the timing
    started = time.perf_counter()
    images = [view.render(f.params) for f in frames]
    render_s = time.perf_counter() - started
    with tempfile.TemporaryDirectory() as tmp:
        writer = open_writer(str(Path(tmp) / "out.mp4"), session.source.fps, (size, size), io.BytesIO())
        started = time.perf_counter()
        for image in images:
            writer.write(image)
        writer.close()
        write_s = time.perf_counter() - started

    bits = 8 * session.stream_bytes / n
    return (f"| {datetime.date.today()} | {clip.name} | {n} | {n / send_s:.1f} | {size}x{size} | "
            f"{n / render_s:.1f} | {n / (render_s + write_s):.1f} | {bits:.0f} | {bits * session.source.fps:.0f} |")


def main() -> None:
    p = ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("clips", nargs="*", type=Path, default=[ROOT / "samples" / "grid_bbaf2n.mpg"])
    p.add_argument("--size", type=int, default=512, help="receiver output size (default 512)")
    args = p.parse_args()
    print("| date | clip | frames | sender fps | output | render fps | render+H.264 fps | bits/frame | bit/s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for clip in args.clips:
        print(bench(clip, args.size), flush=True)


if __name__ == "__main__":
    raise SystemExit(run_main("bench_pipeline.py", lambda: main() or 0))
