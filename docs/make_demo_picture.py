"""docs/demo.png: frames of the bundled clip beside what the receiver draws from the stream: the
whole picture (the person's reference picture warped by their moving face model, fd-enroll's
default) and the paper's shaded generic face (fd-send without a face model). docs/picture_mesh.png:
the scene mesh of the whole picture (docs/picture.md) over the reference picture, then moved.

Run from the repository: .venv/bin/python docs/make_demo_picture.py [--video out/side-by-side.mp4]
(--video: every frame of the clip so, as a video, instead of the pictures; make demo writes it).
"""

import argparse
import tempfile
from pathlib import Path

import cv2
import numpy as np

import facedeform
from facedeform.codec.face_file.format import Face
from facedeform.codec.model.deform import Deformer
from facedeform.codec.model.face_model import load_base_face
from facedeform.codec.render.picture import SceneMesh, frame_placement
from facedeform.common.parameters import EXTENDED_PARAMS, POSE_PARAMS
from facedeform.protocol.stream import Frame, Header, StreamDecoder, steps_for
from facedeform.receiver.face_view import open_view
from facedeform.receiver.output import VideoFileWriter
from facedeform.sender.config import SendConfig
from facedeform.sender.session import SendSession

ROOT = Path(__file__).resolve().parents[1]
CLIP = ROOT / "samples" / "grid_bbaf2n.mpg"
FRAMES = (5, 42, 60)  # rest, mouth open, mouth half open
HEIGHT = 288


def rendered(face_file: str | None, look: str, size: tuple[int, int], frames=FRAMES) -> tuple[list, int]:
    """Each of ``frames`` (None: all) as the receiver draws it (BGR), and the stream's bits per frame."""
    session = SendSession(str(CLIP), SendConfig(), face=None if face_file is None else Face.load(face_file))
    decoder = StreamDecoder()
    events = [e for chunk in session.stream() for e in decoder.feed(chunk)] + decoder.close()
    decoded = [e for e in events if isinstance(e, Frame)]
    face = load_base_face() if face_file is None else Face.load(face_file).model
    view = open_view(look, events[0], face, size)
    images = [cv2.cvtColor(view.render(decoded[i].params), cv2.COLOR_RGB2BGR)
              for i in (range(len(decoded)) if frames is None else frames)]
    return images, round(session.stats()["bits_per_frame"])


def label(image: np.ndarray, text: str) -> None:
    (w, h), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.42, 1)
    image[HEIGHT - 16 - h:HEIGHT - 4, 4:12 + w] //= 3  # a dark band under the text
    cv2.putText(image, text, (8, HEIGHT - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (255, 255, 255), 1, cv2.LINE_AA)


def mesh_figure(face_file: str) -> np.ndarray:
    """The reference picture with the scene mesh (face white, rings yellow), and the whole picture
    drawn with the jaw open and the head turned and moved, its mesh over it and without (BGR)."""
    face = Face.load(face_file).model
    scene = SceneMesh(face, face.picture)
    pose = np.array([0.0, 18.0, 4.0, 0.06, 0.02, 0.1])  # rx, ry, rz, tx, ty, tz
    full = np.zeros(len(EXTENDED_PARAMS))
    full[0] = 12.0  # the jaw
    deformed = Deformer(face).deform_extended(full)
    names = ("theta",) + POSE_PARAMS
    view = open_view("picture", Header(25.0, names, steps_for(names), face.content_id), face,
                     face.picture.image.shape[1::-1])
    moved = cv2.cvtColor(view.render(np.r_[12.0, pose]), cv2.COLOR_RGB2BGR)
    panels = []
    for image, place, verts in ((cv2.cvtColor(face.picture.image, cv2.COLOR_RGB2BGR), scene.reference, face.vertices),
                                (moved.copy(), frame_placement(scene.reference, pose, scene.pivot), deformed)):
        points = np.round(scene.positions(verts, place)[:, :2] * [1, -1] * 16).astype(np.int32)
        rings = scene.triangles[len(face.faces):]
        for tris, colour in ((rings, (0, 200, 255)), (scene.triangles[:len(face.faces)], (255, 255, 255))):
            cv2.polylines(image, list(points[tris]), True, colour, 1, cv2.LINE_AA, shift=4)
        panels.append(image)
    return np.hstack(panels + [moved])


def video(path: str, face_file: str, originals: list) -> None:
    """Every frame: original | whole picture | the paper's shaded face, as an H.264 MP4 that browsers play."""
    size = originals[0].shape[1], originals[0].shape[0]
    picture, _ = rendered(face_file, "picture", size, None)
    shaded, _ = rendered(None, "shaded", (HEIGHT, HEIGHT), None)
    rows = [np.hstack(row) for row in zip(originals, picture, shaded)]
    writer = VideoFileWriter(path, 25.0, rows[0].shape[1::-1])
    for row in rows:
        writer.write(cv2.cvtColor(row, cv2.COLOR_BGR2RGB))
    writer.close()
    print(f"wrote {path} (original | whole picture | paper's shaded face)")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--video", metavar="OUT.mp4", help="write every frame side by side as a video instead")
    args = p.parse_args()
    cap = cv2.VideoCapture(str(CLIP))
    originals = []
    while (frame := cap.read()[1]) is not None:
        originals.append(frame)
    size = originals[0].shape[1], originals[0].shape[0]
    with tempfile.TemporaryDirectory() as tmp:
        face_file = str(Path(tmp) / "me.fdface")
        facedeform.enroll(str(CLIP)).save(face_file)
        if args.video:
            video(args.video, face_file, originals)
            return
        picture, picture_bits = rendered(face_file, "picture", size)
        cv2.imwrite(str(ROOT / "docs" / "picture_mesh.png"), mesh_figure(face_file))
        shaded, shaded_bits = rendered(None, "shaded", (HEIGHT, HEIGHT))
    rows = []
    for k, i in enumerate(FRAMES):
        label(originals[i], f"original, frame {i}")
        label(picture[k], f"whole picture, {picture_bits} bits/frame")
        label(shaded[k], f"paper's shaded face, {shaded_bits} bits/frame")
        rows.append(np.hstack([originals[i], picture[k], shaded[k]]))
    out = ROOT / "docs" / "demo.png"
    cv2.imwrite(str(out), np.vstack(rows))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
