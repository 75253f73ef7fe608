"""docs/demo.png: frames of the bundled clip beside what the receiver renders from the stream.

Run from the repository: .venv/bin/python docs/make_demo_picture.py
"""

from pathlib import Path

import cv2
import numpy as np

from codec.face_model import load_base_face
from protocol.stream import Frame, StreamDecoder
from receiver.face_view import FaceView
from sender.session import SendSession

ROOT = Path(__file__).resolve().parents[1]
FRAMES = (5, 42, 60)  # rest, mouth open, mouth half open
HEIGHT = 288


def main() -> None:
    session = SendSession(str(ROOT / "samples" / "grid_bbaf2n.mpg"))
    decoder = StreamDecoder()
    events = [e for chunk in session.stream() for e in decoder.feed(chunk)] + decoder.close()
    decoded = [e for e in events if isinstance(e, Frame)]
    view = FaceView(events[0], load_base_face(), (HEIGHT, HEIGHT))
    cap = cv2.VideoCapture(str(ROOT / "samples" / "grid_bbaf2n.mpg"))
    originals = [cap.read()[1] for _ in range(max(FRAMES) + 1)]
    rows = []
    for i in FRAMES:
        original = originals[i]
        rendered = cv2.cvtColor(view.render(decoded[i].params), cv2.COLOR_RGB2BGR)
        theta = decoded[i].params[0]
        cv2.putText(rendered, f"frame {i}  theta {theta:.1f} deg", (8, HEIGHT - 10),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.45, (230, 230, 230), 1, cv2.LINE_AA)
        rows.append(np.hstack([original, rendered]))
    out = ROOT / "docs" / "demo.png"
    cv2.imwrite(str(out), np.vstack(rows))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
