"""Time Renderer.render on the MediaPipe canonical face (468 vertices, 898 triangles).

Median milliseconds per frame over FRAMES frames after a warm-up, with numba
pinned to one thread. Also writes /tmp/bench_face*.png to eyeball the result.
Run: .venv/bin/python benchmarks/bench_render.py
"""

import re
import statistics
import sys
import time
from pathlib import Path

import numba
import numpy as np

from codec.camera import Camera
from codec.render import Renderer

FRAMES = 100
MESH = Path(__file__).resolve().parents[1] / "samples" / "base_face" / "canonical_face.pbtxt"
INNER_LIPS = {78, 95, 88, 178, 87, 14, 317, 402, 318, 324, 308, 191, 80, 81, 82, 13,
              312, 311, 310, 415}


def load_face() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices (468, 3) float64 in cm, uv (468, 2), faces (898, 3) int32."""
    text = MESH.read_text()
    vbuf = np.array(re.findall(r"vertex_buffer:\s*(\S+)", text), float).reshape(-1, 5)
    faces = np.array(re.findall(r"index_buffer:\s*(\S+)", text), np.int32).reshape(-1, 3)
    return vbuf[:, :3], vbuf[:, 3:], faces


def checker(n: int = 256, cells: int = 16) -> np.ndarray:
    """(n, n, 3) uint8 two-tone checkerboard texture."""
    i = (np.arange(n) * cells // n) % 2
    mask = (i[:, None] ^ i[None, :]).astype(bool)
    return np.where(mask[..., None], np.uint8([230, 180, 150]), np.uint8([150, 90, 70]))


def time_frames(renderer: Renderer, frames: list, camera: Camera) -> float:
    for verts in frames[:5]:
        renderer.render(verts, camera)
    times = []
    for verts in frames:
        start = time.perf_counter()
        renderer.render(verts, camera)
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1e3


def main() -> None:
    numba.set_num_threads(1)
    verts, uv, faces = load_face()
    centre = (verts.min(0) + verts.max(0)) / 2
    camera = Camera.perspective(30.0, eye=centre + (0, 0, 40.0), target=centre)
    rng = np.random.default_rng(0)
    frames = [verts + rng.normal(0, 0.05, verts.shape) for _ in range(FRAMES)]
    mouth = np.array([set(f) <= INNER_LIPS for f in faces.tolist()])
    print(f"{'size':>9} {'texture':>8} {'ss':>3} {'ms/frame':>9}")
    for size in (256, 512):
        for textured in (False, True):
            for ss in (1, 2):
                extra = dict(uv=uv, texture=checker()) if textured else {}
                renderer = Renderer(faces, size=(size, size), supersample=ss,
                                    background=(40, 40, 48), mouth_faces=mouth, **extra)
                ms = time_frames(renderer, frames, camera)
                print(f"{size}x{size:<4} {str(textured):>8} {ss:>3} {ms:9.2f}")
    opened = verts.copy()
    lower = np.unique(faces[mouth])
    lower = lower[verts[lower, 1] < verts[lower, 1].mean()]
    opened[lower, 1] -= 1.2  # drop the lower inner lip to open the mouth
    for name, mesh, ss in (("", verts, 1), ("_open_ss2", opened, 2)):
        renderer = Renderer(faces, size=(512, 512), supersample=ss, mouth_faces=mouth,
                            background=(40, 40, 48))
        image, _ = renderer.render(mesh, camera)
        write_png(f"/tmp/bench_face{name}.png", image)


def write_png(path: str, image: np.ndarray) -> None:
    import cv2

    cv2.imwrite(path, image[..., ::-1])
    print("wrote", path, file=sys.stderr)


if __name__ == "__main__":
    main()
