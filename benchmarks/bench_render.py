"""Time Renderer.render on the base face (468 vertices, 898 triangles), issue 4's table.

Median milliseconds per frame over FRAMES deformed frames after a warm-up,
with numba pinned to one thread, at 256x256 and 512x512, shaded (albedo) and
textured, supersample 1 and 2, with the receiver's framing, mouth and eyes.
Then the first-call time (import of the renderer to the end of the first
512x512 frame) in fresh processes, with the compile cache cleared and warm.
Also writes /tmp/bench_face_*.png to eyeball the result.
Run: .venv/bin/python benchmarks/bench_render.py
"""

import datetime
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numba
import numpy as np

from facedeform.codec.model.deform import Deformer
from facedeform.codec.model.face_model import load_base_face
from facedeform.codec.render.camera import Camera
from facedeform.codec.render.render import Renderer
from facedeform.common.cli import run_main
from facedeform.receiver.face_view import FIELD_OF_VIEW, FRAMING

FRAMES = 100
FIRST_CALL = """
import time
start = time.perf_counter()
import numpy as np
from facedeform.codec.render.camera import Camera
from facedeform.codec.model.face_model import load_base_face
from facedeform.codec.render.render import Renderer
face = load_base_face()
Renderer(face.faces, size=(512, 512), mouth_faces=face.mouth_faces, eye_faces=face.eye_faces).render(
    face.vertices, Camera.perspective(20.0, eye=(0, 0, 4.4), target=(0, 0, 0)))
print(time.perf_counter() - start)
"""


def receiver_camera(vertices: np.ndarray) -> Camera:
    """The receiver's portrait framing (see receiver.face_view)."""
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    centre = (lo + hi) / 2
    distance = FRAMING * (hi[1] - lo[1]) / 2 / np.tan(np.radians(FIELD_OF_VIEW / 2)) + hi[2] - centre[2]
    return Camera.perspective(FIELD_OF_VIEW, eye=centre + [0, 0, distance], target=centre)


def checker(n: int = 256, cells: int = 16) -> np.ndarray:
    """(n, n, 3) uint8 two-tone checkerboard texture."""
    i = (np.arange(n) * cells // n) % 2
    mask = (i[:, None] ^ i[None, :]).astype(bool)
    return np.where(mask[..., None], np.uint8([230, 180, 150]), np.uint8([150, 90, 70]))


def talking_frames(face) -> list[np.ndarray]:
    """FRAMES (468, 3) meshes: the jaw opening and closing, lips moving a little."""
    deformer, rng = Deformer(face), np.random.default_rng(0)
    frames = []
    for k in range(FRAMES):
        params = np.zeros(13)
        params[0] = 6.0 + 6.0 * np.sin(k / 5.0)
        params[1:] = rng.normal(0.0, 0.005, 12)
        frames.append(deformer.deform(params))
    return frames


def median_ms(renderer: Renderer, frames: list, camera: Camera) -> float:
    for verts in frames[:5]:
        renderer.render(verts, camera)
    times = []
    for verts in frames:
        start = time.perf_counter()
        renderer.render(verts, camera)
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1e3


def first_call_seconds(cache_dir: str) -> float:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir, NUMBA_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", FIRST_CALL], env=env, check=True,
                         capture_output=True, text=True)
    return float(out.stdout.split()[-1])


def main() -> None:
    numba.set_num_threads(1)
    face = load_base_face()
    camera = receiver_camera(face.vertices)
    frames = talking_frames(face)
    parts = dict(mouth_faces=face.mouth_faces, eye_faces=face.eye_faces)
    print(f"Renderer.render, base face, one thread, median of {FRAMES} frames, "
          f"{datetime.date.today().isoformat()}, {numba.config.NUMBA_DEFAULT_NUM_THREADS} cpus, "
          f"load average {os.getloadavg()[0]:.2f} (other processes slow it down)\n")
    print("| size | supersample | shaded ms | textured ms |")
    print("|---|---|---|---|")
    for size in (256, 512):
        for ss in (1, 2):
            cells = []
            for extra in ({}, dict(uv=face.uv, texture=checker())):
                renderer = Renderer(face.faces, size=(size, size), supersample=ss, **parts, **extra)
                cells.append(median_ms(renderer, frames, camera))
            print(f"| {size}x{size} | {ss} | {cells[0]:.2f} | {cells[1]:.2f} |")
    with tempfile.TemporaryDirectory() as cache:
        cold = first_call_seconds(cache)
        warm = first_call_seconds(cache)
    print(f"\nfirst call (import to first 512x512 frame): cold cache {cold:.2f} s, warm cache {warm:.2f} s")
    renderer = Renderer(face.faces, size=(512, 512), supersample=2, **parts)
    for name, verts in (("closed", face.vertices), ("open", frames[8])):
        write_png(f"/tmp/bench_face_{name}.png", renderer.render(verts, camera)[0])


def write_png(path: str, image: np.ndarray) -> None:
    import cv2

    cv2.imwrite(path, image[..., ::-1])
    print("wrote", path, file=sys.stderr)


if __name__ == "__main__":
    raise SystemExit(run_main("bench_render.py", lambda: main() or 0))
