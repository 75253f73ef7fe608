"""The picture layer's codec alone: VP9 coded from the model's picture against VP9 and SVT-AV1 alone.

For each clip (its 256x256 face crop and its speaker's face, enrolled as fd-experiment enrols),
the model's picture of every frame is what a receiver draws at fd-send's defaults (no layer). Every
``--every``-th frame, scaled to ``--side`` pixels, is then coded in one-pass CBR in real time at
each ``--rates`` kbit/s (the video's own share, as the layer gives it) three ways, each decoded:

- ``av1``: SVT-AV1 of the frame alone (PyAV; real-time mode, no lookahead, the first frame a key);
- ``vp9``: VP9 of the frame alone (libvpx, codec/render/vp9.py, the first frame a key);
- ``vp9+model``: VP9 with the model's picture of each frame in its golden reference at both ends,
  after a flat grey key, as the layer codes it (codec/render/frame_video.VideoEncoder and
  VideoDecoder; a frame libvpx drops costs nothing and the one before it is shown again).

Reported per clip, codec and rate: kbit/s spent, the first frame's bytes (with the grey key),
the mean and 5th percentile of the coded frames' PSNR against the frame at that size (mean of R, G,
B), and the same for the model's picture alone at that size. What it isolates: how much the model's
picture saves the video, apart from the blocks, the carry and the rate control of the whole stream.

    .venv/bin/python benchmarks/bench_video_codecs.py /path/to/dev/*.mp4 --rates 2.3 7 --out results/
"""

import json
from fractions import Fraction
from functools import partial
from pathlib import Path

import numpy as np

import facedeform
from facedeform.codec.render import vp9
from facedeform.codec.render.frame_video import VideoDecoder, VideoEncoder, from_yuv, shrunk, to_yuv
from facedeform.common.cli import ArgumentParser, run_main
from facedeform.common.scheduling import kept_scheduling
from facedeform.experiment.clips import crops

#: SVT-AV1's options: one pass, real time, every frame predicted from the last, no lookahead.
AV1_OPTIONS = {"preset": "6", "svtav1-params": "pred-struct=1:keyint=0:scd=0:lookahead=0:rc=2:rtc=1:"
               "hierarchical-levels=0"}


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(10 * np.log10(255 ** 2 / max(1e-9, np.mean((a.astype(np.float64) - b) ** 2))))


def av1(frames: list, size: tuple[int, int], kbps: float, fps: float) -> tuple[list[int], list]:
    """(bytes of each coded frame, the frames decoded) by SVT-AV1 alone."""
    import av

    codec = av.CodecContext.create("libsvtav1", "w")
    codec.width, codec.height, codec.pix_fmt = size[0], size[1], "yuv420p"
    rate = Fraction(fps).limit_denominator(1001)
    codec.time_base, codec.framerate, codec.bit_rate = 1 / rate, rate, int(1000 * kbps)
    codec.options = AV1_OPTIONS
    with kept_scheduling():
        codec.open()
    decoder = av.CodecContext.create("libdav1d", "r")
    decoder.options = {"max_frame_delay": "1"}
    sizes, out = [], []
    for n, frame in enumerate(frames):
        picture = av.VideoFrame.from_ndarray(frame, format="rgb24")
        picture.pts = n
        if n == 0:
            picture.pict_type = av.video.frame.PictureType.I
        data = b"".join(bytes(p) for p in codec.encode(picture))
        sizes.append(len(data))
        out.append(decoder.decode(av.Packet(data))[0].to_ndarray(format="rgb24"))
    return sizes, out


def vp9_coded(frames: list, size: tuple[int, int], kbps: float, fps: float, models: list | None = None
              ) -> tuple[list[int], list]:
    """(bytes of each coded frame, the frames decoded) by VP9, alone (``models`` None: each frame
    coded from the last, the first a key) or as the layer codes it, from the model's picture of each
    frame (codec/render/frame_video.VideoEncoder; a frame libvpx drops costs nothing and the one
    before it is shown again)."""
    if models is None:
        encoder, decoder = vp9.Encoder(size, 1000 * kbps, fps), vp9.Decoder(size)
        coded = [encoder.encode(to_yuv(frame), key=n == 0) for n, frame in enumerate(frames)]
        decoded = [decoder.decode(data) for data in coded]
        if any(planes is None for planes in decoded):
            raise RuntimeError("VP9 did not decode its own frame")
        encoder.close()
        decoder.close()
        return [len(data) for data in coded], [from_yuv(planes, size) for planes in decoded]
    layer_encoder, layer_decoder = VideoEncoder(size, 1000 * kbps, fps), VideoDecoder(size)
    sizes, out = [], []
    for n, (frame, model) in enumerate(zip(frames, models)):
        data = layer_encoder.encode(frame, model, key=n == 0)
        picture = layer_decoder.decode(data, n == 0, lambda _, m=model: m) if data else out[-1]
        if picture is None:
            raise RuntimeError("VP9 did not decode its own frame")
        sizes.append(len(data))
        out.append(picture)
    layer_encoder.close()
    return sizes, out


def run(clip, face, rates: list[float], every: int, side: int) -> list[dict]:
    """Rows of ``clip``: each codec at each rate."""
    chunks = list(facedeform.encode(str(clip.path), face, embed_face=False))
    models = list(facedeform.decode(chunks, face))
    w, h = clip.frames[0].shape[1::-1]
    size = (8 * round(side * w / max(w, h) / 8), 8 * round(side * h / max(w, h) / 8))
    chosen = range(0, min(len(clip.frames), len(models)), every)
    frames = [np.ascontiguousarray(shrunk(clip.frames[i], size)) for i in chosen]
    pictures = [np.ascontiguousarray(shrunk(models[i], size)) for i in chosen]
    fps = clip.fps / every
    seconds = len(frames) / fps
    model_psnr = [psnr(m, f) for m, f in zip(pictures, frames)]
    rows = []
    for kbps in rates:
        for name, coded in (("av1", av1), ("vp9", vp9_coded), ("vp9+model", partial(vp9_coded, models=pictures))):
            sizes, decoded = coded(frames, size, kbps, fps)
            values = [psnr(d, f) for d, f in zip(decoded, frames)]
            rows.append({"clip": clip.name, "codec": name, "asked_kbps": kbps, "size": list(size),
                         "frames": len(frames), "kbps": 8 * sum(sizes) / seconds / 1000, "first_bytes": sizes[0],
                         "psnr": float(np.mean(values)), "psnr_p5": float(np.percentile(values, 5)),
                         "model_psnr": float(np.mean(model_psnr))})
            print(json.dumps(rows[-1]), flush=True)
    return rows


def main() -> None:
    p = ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("clips", nargs="+", type=Path)
    p.add_argument("--rates", nargs="+", type=float, default=[2.3, 7.0], metavar="KBPS",
                   help="the video's kbit/s (default: %(default)s, its share at fd-send --bitrate 4 and 10)")
    p.add_argument("--every", type=int, default=6, help="code every this many frames (default: %(default)s, "
                   "as the layer at 4 kbit/s)")
    p.add_argument("--side", type=int, default=128, help="the video's larger side in pixels (default: %(default)s)")
    p.add_argument("--out", type=Path, default=Path("results"))
    args = p.parse_args()
    if args.every < 1 or args.side < 64 or min(args.rates) <= 0:
        p.error("--every must be at least 1, --side at least 64, and --rates above 0")
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for clip, _ in crops(args.clips):
        half = len(clip.frames) / 2 / clip.fps
        face = facedeform.enroll(str(clip.path), seconds=1.0, motion_seconds=half)
        rows += run(clip, face, args.rates, args.every, args.side)
    (args.out / "video_codecs.json").write_text(json.dumps(rows, indent=1) + "\n")
    print("| clip | kbit/s asked | model's picture alone | av1 | vp9 | vp9+model |")
    print("|---|---|---|---|---|---|")
    for i in range(0, len(rows), 3):
        a, b, c = rows[i:i + 3]
        cells = [f"{r['psnr']:.2f} dB, {r['kbps']:.2f} kbit/s ({r['first_bytes']} B)" for r in (a, b, c)]
        print(f"| {a['clip']} | {a['asked_kbps']:g} | {a['model_psnr']:.2f} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    raise SystemExit(run_main("bench_video_codecs.py", lambda: main() or 0))
