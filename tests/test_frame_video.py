"""The picture layer's video and blocks (codec/render/frame_video.py), apart from a call."""

import os

import cv2
import numpy as np
import pytest

from facedeform.codec.render import frame_video, vp9
from facedeform.codec.render.frame_video import (
    BLOCK,
    VideoEncoder,
    VideoLayer,
    blend,
    blocks_in,
    blocks_of,
    choose_payload,
    decode_blocks,
    drawn_size,
    encode_blocks,
    encode_still,
    shrunk,
    video_parts,
    video_size,
)
from facedeform.common.scheduling import REAL_TIME, _policies

PICTURE = (128, 96)  # w, h


def grey(size: tuple[int, int]) -> np.ndarray:
    """The model's picture the tests' videos are coded from: flat grey at ``size`` (w, h)."""
    return np.full((size[1], size[0], 3), 90, np.uint8)


def frames(n: int, size=(64, 64)) -> list[np.ndarray]:
    """A bright square moving over a gradient."""
    w, h = size
    out = []
    for i in range(n):
        f = np.tile(np.linspace(20, 200, w, dtype=np.uint8)[None, :, None], (h, 1, 3))
        f[10:30, 5 + 2 * i:25 + 2 * i] = (250, 40, 40)
        out.append(f)
    return out


@pytest.mark.parametrize("seed", range(5))
def test_blocks_code_back_to_themselves(seed):
    rng = np.random.default_rng(seed)
    before = rng.random(blocks_of(PICTURE)) < 0.5
    after = before ^ (rng.random(before.shape) < 0.2)
    data = encode_blocks(before, after)
    got, used = decode_blocks(before, data + b"tail")
    np.testing.assert_array_equal(got, after)
    assert used == len(data)
    assert len(encode_blocks(after, after)) <= 1  # no change costs next to nothing


def test_blocks_cut_short_do_not_decode():
    before = np.zeros(blocks_of(PICTURE), bool)
    after = np.random.default_rng(1).random(before.shape) < 0.5
    assert decode_blocks(before, encode_blocks(before, after)[:1]) is None


def test_video_sizes_are_even_at_least_64_and_keep_the_shape():
    assert video_size((256, 256), 64) == (64, 64)
    assert video_size((1920, 1080), 480) == (480, 272)  # multiples of 8
    assert video_size((256, 144), 64) == (112, 64)  # the smaller side at the least
    assert video_size((40, 40), 10) == (64, 64)


def test_both_ends_of_a_video_hold_the_same_frames_and_blocks():
    sender, receiver = VideoLayer(PICTURE), VideoLayer(PICTURE)
    encoder = VideoEncoder((64, 64), 20_000, 25)
    model = grey(PICTURE)
    for seq, frame in enumerate(frames(6)):
        def choose(parts, still, before, odd=seq % 2, moved=seq % 3 != 1):
            return (np.eye(*before.shape, dtype=bool) if odd else before), moved

        video = encoder.encode(frame, grey((64, 64)), key=seq == 0)
        data = sender.make(seq, video, seq == 0, model, None, choose, grey((64, 64)))
        assert receiver.take(seq, data) and receiver.decode_due(seq, grey)
        np.testing.assert_array_equal(receiver.chosen, sender.chosen)
        np.testing.assert_array_equal(receiver.draw(seq, model), sender.draw(seq, model))
    assert sender.frame is not None and np.abs(sender.frame.astype(int) - frames(6)[-1]).mean() < 20


def test_the_video_is_coded_from_the_model_s_picture():
    """Each frame is coded from the model's picture of it as well as from the last frame: a frame the
    model draws well costs a fraction of the same frame coded alone, and a receiver given another
    picture than the sender's does not draw what the sender does."""
    frame = frames(1, (64, 64))[0]
    alone = VideoEncoder((64, 64), 20_000, 25).encode(frame, grey((64, 64)), key=True)
    modelled = VideoEncoder((64, 64), 20_000, 25).encode(frame, frame, key=True)
    assert len(modelled) < 0.5 * len(alone)
    sender, receiver = VideoLayer(PICTURE), VideoLayer(PICTURE)
    keep = lambda parts, still, before: (before, True)  # noqa: E731
    data = sender.make(0, modelled, True, grey(PICTURE), None, keep, frame)
    assert receiver.take(0, data) and receiver.decode_due(0, lambda size: frame)
    np.testing.assert_array_equal(receiver.frame, sender.frame)
    assert np.abs(sender.frame.astype(int) - frame).mean() < 3
    wrong = VideoLayer(PICTURE)
    assert wrong.take(0, data) and wrong.decode_due(0, grey)
    assert np.abs(wrong.frame.astype(int) - frame).mean() > 10


def test_a_frame_that_would_overrun_the_buffer_is_dropped_and_the_next_ones_still_decode():
    """Noise after a still picture at 3 kbit/s is dropped once coded (b""); the frames after it decode
    at a receiver that never saw it, each near its own frame (the encoder went on as without it)."""
    still = frames(1, (64, 64))[0]
    noise = np.random.default_rng(1).integers(0, 256, still.shape, dtype=np.uint8)
    encoder = VideoEncoder((64, 64), 3_000, 4)
    sender, receiver = VideoLayer(PICTURE), VideoLayer(PICTURE)
    keep = lambda parts, picture, before: (before, True)  # noqa: E731
    sent = []
    for seq, frame in enumerate([still] * 4 + [noise] + [still] * 2):
        video = encoder.encode(frame, still, key=seq == 0)
        if not video:
            continue
        sent.append(seq)
        data = sender.make(seq, video, seq == 0, grey(PICTURE), None, keep, still)
        assert receiver.take(seq, data) and receiver.decode_due(seq, lambda size: still)
        np.testing.assert_array_equal(receiver.frame, sender.frame)
        assert np.abs(receiver.frame.astype(int) - frame).mean() < 3
    assert sent == [0, 1, 2, 3, 5, 6]


def test_the_frames_after_a_key_or_a_drop_are_never_dropped():
    """CALM frames after a key, and after a dropped frame, are kept however much they overrun: libvpx
    learns its frames' sizes only from those it keeps (else it drops every other frame)."""
    still = frames(1, (64, 64))[0]
    rng = np.random.default_rng(2)
    encoder = VideoEncoder((64, 64), 3_000, 4)
    kept = [bool(encoder.encode(rng.integers(0, 256, still.shape, dtype=np.uint8), still, key=i == 0))
            for i in range(12)]
    drops = [i for i, k in enumerate(kept) if not k]
    assert drops and drops[0] > frame_video.CALM
    assert all(all(kept[i + 1:i + 1 + frame_video.CALM]) for i in drops)


def test_a_gap_in_the_counter_draws_the_model_alone_until_the_next_key():
    sender, receiver = VideoLayer(PICTURE), VideoLayer(PICTURE)
    encoder = VideoEncoder((64, 64), 20_000, 25)
    model = grey(PICTURE)
    keep = lambda parts, still, before: (before, True)  # noqa: E731
    payloads = [sender.make(seq, encoder.encode(f, grey((64, 64)), key=seq in (0, 4)), seq in (0, 4), model, None,
                            keep, grey((64, 64))) for seq, f in enumerate(frames(6))]
    assert receiver.take(0, payloads[0]) and receiver.decode_due(0, grey)
    assert receiver.take(1, payloads[1]) and receiver.decode_due(1, grey)
    assert not receiver.take(3, payloads[3])  # 2 was lost
    np.testing.assert_array_equal(receiver.draw(1, model), sender.draw(1, model))  # a frame before it, drawn late
    np.testing.assert_array_equal(receiver.draw(3, model), model)
    assert receiver.take(4, payloads[4]) and receiver.decode_due(4, grey)  # the key
    assert receiver.take(5, payloads[5]) and receiver.decode_due(5, grey)
    np.testing.assert_array_equal(receiver.draw(5, model), sender.draw(5, model))


def test_a_payload_whose_frame_the_receiver_did_not_get_is_lost_until_the_next_key():
    """The model's picture of a frame whose parameters were concealed is not the sender's: its payload
    cannot be decoded as the sender did, nor those after it, until a key."""
    sender, receiver = VideoLayer(PICTURE), VideoLayer(PICTURE)
    encoder = VideoEncoder((64, 64), 20_000, 25)
    keep = lambda parts, still, before: (before, True)  # noqa: E731
    payloads = [sender.make(seq, encoder.encode(f, grey((64, 64)), key=seq in (0, 3)), seq in (0, 3), grey(PICTURE),
                            None, keep, grey((64, 64))) for seq, f in enumerate(frames(5))]
    assert receiver.take(0, payloads[0]) and receiver.decode_due(0, grey)
    assert receiver.take(1, payloads[1]) and not receiver.decode_due(1, None)
    assert not receiver.take(2, payloads[2])
    np.testing.assert_array_equal(receiver.draw(2, grey(PICTURE)), grey(PICTURE))
    assert receiver.take(3, payloads[3]) and receiver.decode_due(3, grey)
    np.testing.assert_array_equal(receiver.draw(3, grey(PICTURE)), sender.draw(3, grey(PICTURE)))


def test_blocks_only_hand_blocks_to_the_model_over_the_held_frame():
    sender, receiver = VideoLayer(PICTURE), VideoLayer(PICTURE)
    encoder = VideoEncoder((64, 64), 20_000, 25)
    model = grey(PICTURE)
    none = lambda parts, still, before: (np.zeros_like(before), True)  # noqa: E731
    every = lambda parts, still, before: (np.ones_like(before), True)  # noqa: E731
    key = encoder.encode(frames(1)[0], grey((64, 64)), key=True)
    assert receiver.take(0, sender.make(0, key, True, model, None, none, grey((64, 64))))
    assert receiver.decode_due(0, grey)
    assert sender.make(1, None, False, model, None, none) is None  # nothing changes: nothing to send
    data = sender.make(1, None, False, model, None, every)
    assert data is not None and len(data) <= 8  # a flags byte and the blocks: no video
    assert receiver.take(1, data) and receiver.decode_due(1, grey) and receiver.chosen.all()
    np.testing.assert_array_equal(receiver.draw(1, model), model)  # every block the model's


def test_a_blocks_only_key_or_junk_after_the_blocks_is_refused():
    layer = VideoLayer(PICTURE)
    assert not layer.take(0, b"\x03\x00")
    assert not layer.take(0, b"")
    assert layer.take(0, b"\x01\x00" + b"\x00\x03not vp9") and not layer.decode_due(0, grey)


def _header(bits: str) -> bytes:
    """The bytes of a bit string, padded with zeros."""
    bits += "0" * (-len(bits) % 8)
    return bytes(int(bits[i:i + 8], 2) for i in range(0, len(bits), 8))


def test_the_decoder_refuses_frames_larger_than_its_limit_and_junk():
    """Read from the frame's own header before libvpx allocates anything: a key, or a frame that says
    a size of its own instead of a reference's, larger than the limit; and what is not a shown VP9 frame."""
    large = VideoEncoder((128, 128), 20_000, 25).encode(np.zeros((128, 128, 3), np.uint8), grey((128, 128)), True)
    grey_key = large[2:2 + int.from_bytes(large[:2], "big")]
    assert vp9.frame_size(grey_key) == (128, 128)
    assert vp9.Decoder((64, 64)).decode(grey_key) is None
    assert vp9.Decoder((128, 128)).decode(grey_key).shape == (192, 128)  # I420 planes
    assert vp9.Decoder((64, 64)).decode(b"\x00" * 40) is None
    huge = _header("10" "00" "0" "1" "1" "0" "00" "00000001" + "0000" * 3 + "000" + f"{65535:016b}" * 2)
    assert vp9.frame_size(huge) == (65536, 65536)
    decoder = vp9.Decoder((128, 128))
    assert decoder.decode(grey_key) is not None and decoder.decode(huge + bytes(64)) is None
    assert vp9.frame_size(large[2 + len(grey_key):]) == (0, 0)  # an ordinary frame: a reference's size


def test_blend_draws_the_model_in_its_blocks_and_the_video_elsewhere():
    model = np.full((PICTURE[1], PICTURE[0], 3), 200, np.uint8)
    video = np.full((24, 32, 3), 40, np.uint8)
    rows, columns = blocks_of(PICTURE)
    chosen = np.zeros((rows, columns), bool)
    chosen[:, : columns // 2] = True
    out = blend(video_parts(model, video), chosen, PICTURE)
    assert out.shape == model.shape and out.dtype == np.uint8
    assert (out[:, :BLOCK // 2] == 200).all()  # well inside the model's blocks
    assert (np.abs(out[:, -BLOCK // 2:].astype(int) - 40) <= 1).all()  # well inside the video's
    np.testing.assert_array_equal(blend(video_parts(model, video), np.ones_like(chosen), PICTURE), model)


def test_the_seam_widens_with_the_pixels_a_video_pixel_covers():
    """Model and video meet over a band about twice as wide where the video has half the picture's
    side, and no wider at a quarter (SEAM); given the picture's size, as wide as without a size."""
    picture = (256, 64)
    model = np.full((picture[1], picture[0], 3), 200, np.uint8)
    chosen = np.zeros(blocks_of(picture), bool)
    chosen[:, : chosen.shape[1] // 2] = True
    video = np.full((16, 64, 3), 40, np.uint8)

    def band(video_size):
        row = blend(video_parts(model, video), chosen, picture, video_size)[picture[1] // 2, :, 0].astype(int)
        return int(np.count_nonzero((row > 42) & (row < 198)))

    same, half, quarter = band(picture), band((128, 32)), band((64, 16))
    assert same == band(None) and 1.7 * same < half == quarter
    assert (blend(video_parts(model, video), chosen, picture, (64, 16))[:, :BLOCK // 2] == 200).all()


def test_blocks_in_a_box_and_a_favoured_model():
    inside = blocks_in((40.0, 10.0, 70.0, 33.0), PICTURE)
    assert inside.shape == blocks_of(PICTURE) and inside.sum() == 4  # columns 1-2, rows 0-1
    assert inside[0, 1] and inside[1, 2] and not inside[0, 0] and not inside[2, 1]
    frame = np.full((PICTURE[1], PICTURE[0], 3), 100, np.uint8)
    model, video = frame + 12, np.full((24, 32, 3), 106, np.uint8)  # the video four times as near (squared)
    before = np.zeros(blocks_of(PICTURE), bool)
    parts = video_parts(model, video)
    assert not choose_payload(parts, model, frame, before)[0].any()
    assert choose_payload(parts, model, frame, before, favour=np.where(inside, 8.0, 1.0))[0].sum() == 4


def test_a_frame_shrunk_by_halves_is_within_a_level_of_one_step():
    frame = np.random.default_rng(3).integers(0, 256, (216, 384, 3), dtype=np.uint8)
    for side in (192, 96, 48):
        size = (side, round(side * 216 / 384))
        once = cv2.resize(frame, size, interpolation=cv2.INTER_AREA)
        got = shrunk(frame, size)
        assert got.shape == once.shape and np.abs(got.astype(int) - once).max() <= 1
        assert (got == once).all() == (side == 192)  # a half: one step
    # no whole number of times smaller: halved while at least twice, then the rest of the way
    half = cv2.resize(frame, (192, 108), interpolation=cv2.INTER_AREA)
    np.testing.assert_array_equal(shrunk(frame, (100, 56)), cv2.resize(half, (100, 56), interpolation=cv2.INTER_AREA))


def test_the_model_s_picture_of_a_video_frame_is_drawn_at_twice_the_video_s_side_or_more():
    """At the picture's size unless a half of it still has twice the video's larger side."""
    assert drawn_size((256, 256), (128, 128)) == (256, 256)
    assert drawn_size((1280, 720), (640, 360)) == (1280, 720)
    assert drawn_size((1920, 1080), (480, 272)) == (960, 540)
    assert drawn_size((3840, 2160), (480, 272)) == (960, 540)
    assert drawn_size((1921, 1080), (240, 136)) == (1921, 1080)  # an odd side is not halved


def textured_disc(side: int, dx: int) -> np.ndarray:
    """(side, side, 3) uint8: a disc of fine stripes and spots on a soft background, ``dx`` pixels right
    of the middle: a face's detail where the model draws it (dx 0) or where the video shows it."""
    ys, xs = np.mgrid[:side, :side].astype(np.float32)
    inside = (xs - side / 2 - dx) ** 2 + (ys - side / 2) ** 2 < (side / 3) ** 2
    texture = 128 + 60 * np.sin((xs - dx) * 1.3) * np.cos(ys * 0.9) + 30 * np.sin((xs - dx + ys) * 0.4)
    grey = np.where(inside, texture, 60 + ys / 4)
    return np.repeat(np.clip(grey, 0, 255).astype(np.uint8)[:, :, None], 3, axis=2)


@pytest.mark.parametrize("dx", [-5, 3, 6])
def test_the_model_s_detail_lands_where_the_video_shows_it(dx, monkeypatch):
    """The model draws the disc a few pixels from where the frame has it; the video (half the side)
    shows the frame's place but not its stripes. Moved by the flow, the model's detail sharpens the
    video where the frame has it: less than half the error of the detail added where the model drew it."""
    side = 128
    model, frame = textured_disc(side, 0), textured_disc(side, dx)
    video = shrunk(frame, (side // 2, side // 2))
    none = np.zeros(blocks_of((side, side)), bool)

    def error(parts) -> float:
        drawn = blend(parts, none, (side, side), (side // 2, side // 2))
        return float(np.mean((drawn.astype(float) - frame) ** 2))

    moved = error(video_parts(model, video))
    monkeypatch.setattr(frame_video, "ALIGNED", 0)
    assert moved < 0.5 * error(video_parts(model, video))


@pytest.mark.parametrize("dx", [-2, 3])
def test_the_model_s_blocks_draw_it_where_the_video_shows_it(dx, monkeypatch):
    """The model draws the disc a few pixels from where the frame (and the video, half its side) has
    it: its blocks draw it moved there, with a twentieth of the error of the model where it is; where
    it is right, it stays within the flow's noise."""
    side = 128
    model, frame = textured_disc(side, 0), textured_disc(side, dx)
    video, every = shrunk(frame, (side // 2, side // 2)), np.ones(blocks_of((side, side)), bool)

    def error(image) -> float:
        return float(np.mean((image.astype(float) - frame) ** 2))

    off = error(model)
    assert error(blend(video_parts(model, video), every, (side, side), video.shape[1::-1])) < 0.05 * off
    assert error(blend(video_parts(frame, video), every, (side, side), video.shape[1::-1])) < 0.005 * off
    monkeypatch.setattr(frame_video, "ALIGNED", 0)  # no flow: the model as it is
    np.testing.assert_array_equal(blend(video_parts(model, video), every, (side, side), video.shape[1::-1]), model)


def test_a_payload_moves_the_model_only_where_that_draws_the_frame_nearer():
    """Where the video shows the disc 3 pixels from where a right model has it (a blurred or coarse
    video the flow follows), the payload keeps the model where it is; where the model is the one off,
    it moves it onto the video."""
    side = 128
    every = np.ones(blocks_of((side, side)), bool)
    right, off = textured_disc(side, 0), textured_disc(side, 3)
    video = shrunk(off, (side // 2, side // 2))
    assert not choose_payload(video_parts(right, video), right, right, every)[1]
    assert choose_payload(video_parts(right, video), right, off, every)[1]


def test_both_ends_draw_a_still_payload_s_model_where_it_is():
    sender, receiver = VideoLayer((128, 128)), VideoLayer((128, 128))
    encoder = VideoEncoder((64, 64), 20_000, 25)
    model, video = textured_disc(128, 0), shrunk(textured_disc(128, 3), (64, 64))
    for seq, moved in enumerate((True, False, True, False)):
        data = sender.make(seq, encoder.encode(video, grey((64, 64)), key=seq == 0), seq == 0, model, None,
                           lambda parts, still, before, moved=moved: (np.ones_like(before), moved), grey((64, 64)))
        assert receiver.take(seq, data) and receiver.decode_due(seq, grey)
        drawn = receiver.draw(seq, model)
        np.testing.assert_array_equal(drawn, sender.draw(seq, model))
        assert np.array_equal(drawn, model) != moved  # moved: onto the video's disc, 3 pixels right


def test_the_model_s_border_is_not_moved(monkeypatch):
    """A flow that finds the video 2 pixels below the model everywhere moves the model's inside by
    that and fades to nothing at the picture's border, where the flow has nothing beyond to match."""
    side = 128
    model = textured_disc(side, 0)
    model[:2] = 0  # a dark line along the top, as a frame's border may have
    down = np.zeros((side // 2, side // 2, 2), np.float32)
    down[..., 1] = -1.0  # each pixel taken from 1 of the flow's pixels (2 of the picture's) above
    monkeypatch.setattr(frame_video, "_alignment", lambda *_: down)
    moved = video_parts(model, shrunk(model, (side // 2, side // 2)))[0]
    np.testing.assert_array_equal(moved[:2], model[:2])
    middle = slice(side // 2 - 20, side // 2 + 20)
    np.testing.assert_array_equal(moved[middle, middle], model[side // 2 - 22:side // 2 + 18, middle])


def test_the_parts_are_the_same_on_any_number_of_threads():
    """Both ends must draw the same pixels, whatever threads OpenCV has on each."""
    model, video = textured_disc(128, 0), shrunk(textured_disc(128, 4), (64, 64))
    threads = cv2.getNumThreads()
    try:
        cv2.setNumThreads(1)
        one = video_parts(model, video)
    finally:
        cv2.setNumThreads(threads)
    for mine, theirs in zip(one, video_parts(model, video), strict=True):
        np.testing.assert_array_equal(mine, theirs)


def test_where_nothing_was_moved_a_difference_is_disagreement(monkeypatch):
    """A video 20 levels from the model agrees where the detail was moved onto it (what is left is the
    video's coding) and not where it was not (a misplaced edge, where the detail draws a double one)."""
    model, video = np.full((128, 128, 3), 120, np.uint8), np.full((64, 64, 3), 100, np.uint8)
    assert (video_parts(model, video)[3] == 1).all()
    monkeypatch.setattr(frame_video, "ALIGNED", 0)
    assert (video_parts(model, video)[3] == 0).all()


def real_time_threads() -> set[int]:
    return {tid for tid, (policy, _) in _policies().items() if policy in REAL_TIME}


@pytest.mark.skipif(not os.path.isdir("/proc/self/task") or not REAL_TIME, reason="Linux's scheduling policies")
def test_the_still_encoder_leaves_no_thread_real_time():
    """Opened as root, SVT-AV1 (the face file's still pictures) makes the caller's thread and its own
    SCHED_FIFO 99; a spinning child process (chromium, in the viewer's test) inherited it and starved
    the machine."""
    before = real_time_threads()
    encode_still(np.zeros((64, 64, 3), np.uint8), 30)
    assert real_time_threads() <= before
    assert os.sched_getscheduler(0) not in REAL_TIME


def test_a_video_of_the_picture_s_size_needs_no_flow(monkeypatch):
    """The model's detail is nothing where the video is as large as the picture, so the flow is
    skipped there (that this draws the pixels of the flow's path was checked once, by hand: the flow
    cannot be forced on such a video)."""
    model, video = textured_disc(64, 0), textured_disc(64, 3)
    chosen = np.zeros(blocks_of((64, 64)), bool)
    chosen[0, 0] = True
    drawn = blend(video_parts(model, video), chosen, (64, 64))
    assert not video_parts(model, video)[2].any()
    monkeypatch.setattr(frame_video, "_alignment", lambda *_: pytest.fail("no flow is needed"))
    np.testing.assert_array_equal(blend(video_parts(model, video), chosen, (64, 64)), drawn)
