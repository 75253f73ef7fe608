"""Decoder speed of the whole picture (receiver.face_view.PictureView): ms per frame on one core.

A face enrolled from the bundled clip, its reference picture scaled to SIZE,
drawn with talking parameters (the jaw and lips moving, the head turning and
moving), with a still camera and with one that pans, zooms and rolls every
frame (the picture warped each time); the deformation, placement and rendering
are timed together, as fd-recv runs them per frame.

    .venv/bin/python benchmarks/bench_picture_speed.py [--size 512] [--frames 300]
"""

import os
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from facedeform.codec.face_file.format import Face
from facedeform.codec.model.face_model import ReferencePicture
from facedeform.codec.render.picture import Placement
from facedeform.common.cli import ArgumentParser, run_main
from facedeform.common.parameters import GLOBAL_PARAMS
from facedeform.protocol.stream import Header, steps_for
from facedeform.receiver.face_view import PictureView

ROOT = Path(__file__).resolve().parents[1]
CLIP = ROOT / "samples" / "grid_bbaf2n.mpg"


def main() -> None:
    p = ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=512)
    p.add_argument("--frames", type=int, default=300)
    args = p.parse_args()
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "grid.fdface"
        subprocess.run([sys.executable, "-m", "facedeform.sender.enroll", str(CLIP), "-o", str(path),
                        "--motion", "0", "-q"], check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
        face = Face.load(path).model
    # the picture scaled to size x size (a square crop of it), the projection with it
    image = face.picture.image
    side = min(image.shape[:2])
    x0, y0 = (image.shape[1] - side) // 2, (image.shape[0] - side) // 2
    factor = args.size / side
    place = Placement.from_matrix(face.picture.projection)
    place = Placement(place.scale * factor, place.rotation, (place.shift - [x0, -y0, 0.0]) * factor)
    square = cv2.resize(image[y0:y0 + side, x0:x0 + side], (args.size, args.size), interpolation=cv2.INTER_LINEAR)
    face = replace(face, picture=ReferencePicture(square, place.matrix()))
    names = ("theta", "v2y", "v3y", "rx", "ry", "rz", "tx", "ty", "tz") + GLOBAL_PARAMS
    view = PictureView(Header(25.0, names, steps_for(names), face.content_id), face, (args.size, args.size))
    t = np.arange(args.frames) / 25.0
    talking = np.column_stack([8 + 8 * np.sin(5 * t), 0.01 * np.sin(7 * t), -0.01 * np.sin(6 * t),
                               4 * np.sin(t), 10 * np.sin(0.7 * t), 2 * np.sin(0.5 * t),
                               0.05 * np.sin(0.9 * t), 0.03 * np.sin(1.1 * t), 0.1 * np.sin(0.3 * t)])
    camera = np.column_stack([0.05 * np.sin(0.4 * t), 0.02 * np.sin(0.3 * t), 0.03 * np.sin(0.2 * t), np.sin(t)])
    view.render(np.r_[talking[0], camera[0]])  # compile
    for what, moving in (("still camera", 0.0), ("moving camera", 1.0)):
        start, cpu = time.perf_counter(), time.process_time()
        for row in np.column_stack([talking, moving * camera]):
            view.render(row)
        ms = (time.process_time() - cpu) / len(t) * 1000
        wall = (time.perf_counter() - start) / len(t) * 1000
        print(f"whole picture {args.size}x{args.size}, {what}: {ms:.2f} ms of CPU per frame ({1000 / ms:.0f} "
              f"frames/s on one core; {wall:.2f} ms wall clock on this machine now)")


if __name__ == "__main__":
    raise SystemExit(run_main("bench_picture_speed.py", lambda: main() or 0))
