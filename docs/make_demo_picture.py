"""docs/demo.png: frames of the bundled clip beside what the receiver renders from the stream,
with the generic shaded face and with the person's own face model and motion basis (fd-enroll).

Run from the repository: .venv/bin/python docs/make_demo_picture.py
"""

import tempfile
from pathlib import Path

import cv2
import numpy as np

from codec.face_file import load_face_file
from codec.face_model import load_base_face
from protocol.stream import Frame, StreamDecoder
from receiver.face_view import FaceView
from sender.enroll import main as enroll
from sender.config import SendConfig
from sender.session import SendSession

ROOT = Path(__file__).resolve().parents[1]
CLIP = ROOT / "samples" / "grid_bbaf2n.mpg"
FRAMES = (5, 42, 60)  # rest, mouth open, mouth half open
HEIGHT = 288


def rendered(face_file: str | None) -> tuple[list, int]:
    """Each chosen frame as the receiver draws it, and the stream's bits per frame."""
    session = SendSession(str(CLIP), SendConfig(face_file=face_file))
    decoder = StreamDecoder()
    events = [e for chunk in session.stream() for e in decoder.feed(chunk)] + decoder.close()
    decoded = [e for e in events if isinstance(e, Frame)]
    face = load_base_face() if face_file is None else load_face_file(face_file)
    view = FaceView(events[0], face, (HEIGHT, HEIGHT))
    images = [cv2.cvtColor(view.render(decoded[i].params), cv2.COLOR_RGB2BGR) for i in FRAMES]
    return images, round(session.stats()["bits_per_frame"])


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        face_file = str(Path(tmp) / "me.fdface")
        enroll([str(CLIP), "-o", face_file, "-q"])
        generic, generic_bits = rendered(None)
        personal, personal_bits = rendered(face_file)
    cap = cv2.VideoCapture(str(CLIP))
    originals = [cap.read()[1] for _ in range(max(FRAMES) + 1)]
    rows = []
    for k, i in enumerate(FRAMES):
        for image, text in ((generic[k], f"generic face, {generic_bits} bits/frame"),
                            (personal[k], f"own face model, {personal_bits} bits/frame")):
            cv2.putText(image, text, (8, HEIGHT - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (230, 230, 230), 1,
                        cv2.LINE_AA)
        cv2.putText(originals[i], f"original, frame {i}", (8, HEIGHT - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.42,
                    (255, 255, 255), 1, cv2.LINE_AA)
        rows.append(np.hstack([originals[i], generic[k], personal[k]]))
    out = ROOT / "docs" / "demo.png"
    cv2.imwrite(str(out), np.vstack(rows))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
