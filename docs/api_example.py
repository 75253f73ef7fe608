"""The library API on a clip: enrol the speaker, encode the clip, decode it, and measure it.

    python docs/api_example.py [VIDEO]      (default: the bundled GRID clip)

Prints the stream's size and rate and the decoded picture's PSNR against the
original frames. Runs from any directory once facedeform is installed.
"""

import sys
from pathlib import Path

import cv2
import numpy as np

import facedeform

CLIP = Path(__file__).resolve().parents[1] / "samples" / "grid_bbaf2n.mpg"


def main(video: str) -> None:
    face = facedeform.enroll(video)  # once, before the call: both ends hold it
    print(f"face model {face.id[:12]}: {len(face.data)} bytes")
    stream = b"".join(facedeform.encode(video, face, embed_face=False))  # the receiver holds the face
    psnr = []
    capture = cv2.VideoCapture(video)
    for decoded in facedeform.decode(stream, face):
        ok, original = capture.read()
        error = np.mean((decoded.astype(np.float64) - original[..., ::-1]) ** 2)
        psnr.append(10 * np.log10(255 ** 2 / max(error, 1e-10)))
    fps = capture.get(cv2.CAP_PROP_FPS) or 25.0
    print(f"{len(psnr)} frames, stream {len(stream)} bytes ({8e-3 * len(stream) * fps / len(psnr):.2f} kbit/s "
          f"with its header), PSNR {np.mean(psnr):.1f} dB mean, {np.min(psnr):.1f} dB worst")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else str(CLIP))
