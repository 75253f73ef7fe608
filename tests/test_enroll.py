"""fd-enroll on the bundled clip: a personal model that differs from the generic face, and one-line errors."""


import cv2
import numpy as np
import pytest

from facedeform.codec.face_file.format import Face, face_id
from facedeform.codec.model.face_model import load_base_face
from facedeform.codec.render.eyelids import LIDS
from facedeform.codec.render.picture import face_texture
from facedeform.sender import enrolment, tracker
from facedeform.sender.calibrate import LOWER_LIP
from facedeform.sender.enroll import main
from tests.support import CLIP


def one_line_error(capsys, code):
    err = capsys.readouterr().err
    assert code != 0 and err.startswith("fd-enroll: ") and err.count("\n") == 1, err
    return err


@pytest.mark.parametrize("choice", [[], ["--frame", "3"]])
def test_enrolment_writes_a_personal_textured_model(tmp_path, capsys, choice):
    out = tmp_path / "me.fdface"
    assert main([str(CLIP), "-o", str(out), *choice]) == 0
    printed = capsys.readouterr().out.strip()
    face = Face.load(out).model
    assert printed == face.content_id == face_id(out.read_bytes())
    generic = load_base_face()
    assert np.abs(face.vertices - generic.vertices).max() > 0.01
    np.testing.assert_allclose(face.vertices[10, 1] - face.vertices[152, 1], 1.0, atol=1e-5)
    assert face.texture is None  # the reference picture textures the face
    texture, uv = face_texture(face)
    assert texture is face.picture.image and np.all((uv > 0) & (uv < 1))
    inside = (uv[:, 0] * texture.shape[1]).astype(int), ((1 - uv[:, 1]) * texture.shape[0]).astype(int)
    skin = texture[inside[1], inside[0]].astype(float)
    assert skin.std(axis=0).min() > 10 and 50 < skin.mean() < 230  # a face, not a flat fill
    # mesh, 12 patterns over every vertex (float16: 2.8 KB each), and the reference picture (under 25 KB)
    assert out.stat().st_size < 16_000 + 12 * 2_810 + 25_000


def test_the_reference_picture_is_the_frame_with_the_face_placed_in_it(tmp_path, capsys):
    from facedeform.sender.tracker import FaceTracker

    out = tmp_path / "me.fdface"
    assert main([str(CLIP), "-o", str(out), "--frame", "3", "--motion", "0"]) == 0
    assert "reference picture 360x288" in capsys.readouterr().err
    face = Face.load(out).model
    capture, tracker = cv2.VideoCapture(str(CLIP)), FaceTracker()
    for _ in range(4):  # tracked from the first frame on, as enrolment tracks the clip
        ok, frame = capture.read()
        landmarks = tracker.track(frame)
    picture = face.picture.image
    assert picture.shape == frame.shape
    assert np.abs(picture.astype(float) - cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)).mean() < 3  # WebP-coded
    projected = np.column_stack([face.vertices, np.ones(len(face.vertices))]) @ face.picture.projection.T
    np.testing.assert_allclose(projected[:, :2], landmarks[:, :2], atol=0.05)


def test_no_picture_leaves_it_out(tmp_path, capsys):
    out = tmp_path / "me.fdface"
    assert main([str(CLIP), "-o", str(out), "--motion", "0", "--no-picture"]) == 0
    assert "no reference picture" in capsys.readouterr().err
    face = Face.load(out).model
    assert face.picture is None and face.texture is not None


def test_auto_choice_is_a_closed_mouth_frame(tmp_path, capsys):
    assert main([str(CLIP), "-o", str(tmp_path / "a.fdface")]) == 0
    err = capsys.readouterr().err
    gap = float(err.split("lip gap ")[1].split(",")[0])
    assert gap < 0.05, err


def test_the_neutral_frame_is_not_a_blink_even_where_its_mouth_is_the_most_closed(monkeypatch):
    """A reference picture of shut eyes would draw every frame of the call with them half shut."""
    base = load_base_face()
    pixels = (base.vertices * [200.0, -200.0, 200.0] + [128.0, 128.0, 0.0]).astype(np.float32)
    faces = []
    for apart, shut in ((0.5, True), (2.0, False), (1.5, False), (3.0, False)):  # the blink's lips the most closed
        face = pixels.copy()
        face[LOWER_LIP, 1] += apart
        for upper, lower in LIDS if shut else ():
            face[upper] = face[lower]
        faces.append(face)

    class Tracked:
        def __init__(self) -> None:
            self._seen = iter(faces)

        def track(self, frame):
            return next(self._seen)

    class Clip:
        fps = 4.0
        path = "clip"

        def frames(self):
            return (np.zeros((256, 256, 3), np.uint8) for _ in faces)

    monkeypatch.setattr(tracker, "FaceTracker", Tracked)
    assert enrolment.first_seconds(Clip(), base, None, 1.0).index == 2  # the most closed of the open-eyed
    assert enrolment.first_seconds(Clip(), base, 0, 1.0).index == 0  # asked for, it is taken


def test_missing_file(tmp_path, capsys):
    code = main([str(tmp_path / "none.mp4"), "-o", str(tmp_path / "x.fdface")])
    assert "no such file" in one_line_error(capsys, code)


def test_not_a_video(tmp_path, capsys):
    bogus = tmp_path / "notes.mp4"
    bogus.write_text("not a video at all\n" * 50)
    code = main([str(bogus), "-o", str(tmp_path / "x.fdface")])
    assert "not a video" in one_line_error(capsys, code)


def test_no_face(tmp_path, capsys):
    blank = tmp_path / "blank.avi"
    writer = cv2.VideoWriter(str(blank), cv2.VideoWriter_fourcc(*"MJPG"), 25, (128, 96))
    for _ in range(10):
        writer.write(np.full((96, 128, 3), 90, np.uint8))
    writer.release()
    code = main([str(blank), "-o", str(tmp_path / "x.fdface")])
    assert "no face" in one_line_error(capsys, code)
    assert not (tmp_path / "x.fdface").exists()


def test_frame_beyond_the_clip(tmp_path, capsys):
    code = main([str(CLIP), "--frame", "100000", "-o", str(tmp_path / "x.fdface")])
    assert "frame 100000: the clip has only" in one_line_error(capsys, code)


def test_unknown_option(capsys):
    with pytest.raises(SystemExit) as info:
        main([str(CLIP), "-o", "x.fdface", "--bogus"])
    one_line_error(capsys, info.value.code)


def test_the_speakers_shut_eyes_come_from_a_blink_not_from_a_look_down():
    """ShutEyes keeps the least open eyes that open again within half a second (enrolment.AROUND); eyes
    lowered and kept low (a look down, a squint) are not a blink, however deep."""
    base = load_base_face()
    facing = (base.vertices * [200.0, -200.0, -200.0] + [128.0, 128.0, 0.0]).astype(np.float32)
    turned = (base.vertices * [200.0, -200.0, 200.0] + [128.0, 128.0, 0.0]).astype(np.float32)  # by 40 degrees

    def eyes(open_: float, pixels: np.ndarray) -> np.ndarray:
        face = pixels.copy()
        for upper, lower in LIDS:
            face[upper] = face[lower] + open_ * (face[upper] - face[lower])
        return face

    def kept(openings, pixels=facing) -> int | None:
        shut = enrolment.ShutEyes(base, fps=4.0)  # half a second: two frames either side
        for index, open_ in enumerate(openings):
            shut.see(np.full((8, 8, 3), index, np.uint8), None if open_ is None else eyes(open_, pixels))
        return None if shut.frame is None else int(shut.frame[0][0, 0, 0])

    assert kept([1, 1, 0.5, 0.2, 1, 1, 0.1, 1, 1]) == 6  # the deeper of two blinks
    assert kept([1, 1, 0.8, 0.5, 0.3, 0.2, 0.2, 0.2, 0.2]) is None  # lowered and kept low
    assert kept([1, 1, 0.6, 0.4, 0.4, 0.4, 0.3, 0.3]) is None
    assert kept([1, 1, 0.2, 0.9, 1, 0.1, None, None, None]) == 2  # the face lost before the eyes opened
    assert kept([1, 1, 0.9, 0.85, 0.9, 1]) is None  # a flicker, not a blink
    assert kept([1, 1, 0.2, 1, 1], turned) is None  # a blink with the head turned: not laid on a frontal face


def test_a_budget_takes_a_coarser_picture_and_a_negative_one_is_refused(tmp_path, capsys):
    """The bundled clip's face is within the default budget; one of 1 byte takes the coarsest picture
    and keeps everything else."""
    files = {}
    for budget in ("0", "1"):
        files[budget] = tmp_path / f"{budget}.fdface"
        assert main([str(CLIP), "-o", str(files[budget]), "--frame", "3", "--motion", "0", "--budget", budget]) == 0
    fine, coarse = (Face.load(files[b]).model for b in ("0", "1"))
    assert files["1"].stat().st_size < files["0"].stat().st_size
    np.testing.assert_array_equal(fine.vertices, coarse.vertices)
    np.testing.assert_array_equal(fine.picture.mouth, coarse.picture.mouth)
    assert np.abs(fine.picture.image.astype(float) - coarse.picture.image).mean() > 0.5
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit:
        main([str(CLIP), "-o", str(tmp_path / "x.fdface"), "--budget", "-1"])
    assert exit.value.code == 2 and "--budget takes a number of bytes" in capsys.readouterr().err
