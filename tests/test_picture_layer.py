"""The picture layer: renewals of the receiver's picture under a rate, in a closed loop."""

import tracemalloc
from contextlib import contextmanager

import numpy as np
import pytest

import facedeform
from facedeform.codec.renewal import decode_renewal, encode_renewal
from facedeform.protocol.framing import PICTURE, SYNC, build, packet_size, packet_type, varint
from facedeform.protocol.stream import DatagramDecoder, Frame, Picture, StreamDecoder, frame_bytes
from facedeform.receiver.face_view import PictureView
from facedeform.sender import picture_layer
from facedeform.sender.config import SendConfig
from facedeform.sender.session import SendSession
from tests.support import CLIP

RATE = 10.0  # kbit/s


@pytest.fixture(scope="module")
def face():
    return facedeform.enroll(str(CLIP), motion_seconds=2.0)


@contextmanager
def sender_pictures():
    """The sender's own picture of every frame (what its picture layer reconstructs), as a list
    filled while the context lasts."""
    pictures: list[np.ndarray] = []
    original = picture_layer.PictureLayer.step

    def step(self, *args, **kwargs):
        out = original(self, *args, **kwargs)
        pictures.append(self.picture.copy())
        return out

    picture_layer.PictureLayer.step = step
    try:
        yield pictures
    finally:
        picture_layer.PictureLayer.step = original


@pytest.fixture(scope="module")
def call(face):
    """(stream chunks, the sender's own picture of every frame, bits of each frame's packets) at RATE."""
    with sender_pictures() as pictures:
        session = SendSession(str(CLIP), SendConfig(bitrate=RATE * 1000, embed_face=False), face=face)
        chunks, bits, sent = [], [], 0
        for packets in session.packets():
            if packets:
                chunks.append(frame_bytes(packets, session.sealed))
            if len(chunks) > 1:  # per frame, after the header
                total = 8 * (sum(map(len, chunks)) - len(chunks[0]))
                bits += [0] * (session.frame_count - len(bits))
                bits[-1] += total - sent
                sent = total
    assert session.stats()["picture_renewals"] > 0
    return chunks, pictures, np.array(bits)


def packets_of(stream: bytes) -> list[bytes]:
    """The stream cut at each packet with a sync byte (a frames packet keeps the deltas after it)."""
    cuts, pos = [], 0
    while pos < len(stream):
        start = pos
        if stream[pos] == SYNC and packet_type(stream[pos + 1]) == PICTURE:
            pos += 1 + packet_size(stream, pos + 1)
        else:
            pos = stream.find(bytes([SYNC]) + bytes([PICTURE << 5]), pos + 1)
            pos = len(stream) if pos < 0 else pos
        cuts.append(stream[start:pos])
    return cuts


def test_the_receiver_draws_what_the_sender_reconstructed_bit_for_bit(face, call):
    chunks, pictures, _ = call
    drawn = list(facedeform.decode(chunks, face))
    assert len(drawn) == len(pictures)
    for mine, theirs in zip(pictures, drawn):
        np.testing.assert_array_equal(mine, theirs)


def test_the_layer_shows_what_the_model_cannot(face):
    """The light goes up after the first second: the model-only picture stays as it was, the
    picture layer brings it most of the way to the frames."""
    frames = [f[..., ::-1] for f in facedeform.sender.sources.VideoSource(CLIP).frames()]
    lit = [f if i < 25 else np.clip(f.astype(np.int16) + 40, 0, 255).astype(np.uint8) for i, f in enumerate(frames)]

    def error(kbps=None):
        options = {} if kbps is None else {"bitrate": kbps * 1000}
        drawn = list(facedeform.decode(facedeform.encode(iter(lit), face, embed_face=False, **options), face))
        return np.mean([np.mean((a.astype(float) - b) ** 2) for a, b in zip(drawn[40:], lit[40:])])

    model_only, layered = error(), error(RATE)
    assert layered < 0.25 * model_only


def test_without_its_picture_layer_a_stream_decodes_to_the_model_only_picture(face, call):
    chunks, _, _ = call
    stream = b"".join(chunks)
    stripped = b"".join(c for c in packets_of(stream) if not c.startswith(bytes([SYNC, PICTURE << 5])))
    assert len(stripped) < len(stream)
    decoder = StreamDecoder()
    events = decoder.feed(stripped) + decoder.close()
    assert not decoder.stats.damaged and not any(isinstance(e, Picture) for e in events)
    params = [e.params for e in events if isinstance(e, Frame)]
    view = PictureView(events[0], face.model, (360, 288))
    expected = [view.render(p, i).copy() for i, p in enumerate(params)]
    for got, want in zip(facedeform.decode(stripped, face), expected, strict=True):
        np.testing.assert_array_equal(got, want)


def test_the_rate_is_kept_within_a_tenth_over_any_two_seconds(call):
    _, _, bits = call
    window = 50  # frames: 2 s at 25 fps
    assert len(bits) > window
    sums = np.convolve(bits, np.ones(window), mode="valid")
    assert sums.max() <= 1.1 * RATE * 1000 * 2.0
    assert bits.sum() * 25 / len(bits) > 0.7 * RATE * 1000  # and the rate is used


def test_a_renewal_fits_its_budget_and_decodes_to_its_size():
    residual = np.random.default_rng(0).integers(100, 156, (64, 80, 3), dtype=np.uint8)
    for budget in (120, 400, 2000):
        data = encode_renewal(residual, budget)
        assert data is not None and len(data) <= budget
        assert decode_renewal(data, (80, 64)).shape == (64, 80, 3)
    assert encode_renewal(residual, 10) is None


def webp_header_only(width: int, height: int) -> bytes:
    """A lossless WebP header declaring width x height, with no image data after it."""
    bits = (width - 1) | (height - 1) << 14
    body = b"\x2f" + bits.to_bytes(4, "little")
    return b"RIFF" + (4 + 8 + len(body)).to_bytes(4, "little") + b"WEBPVP8L" + len(body).to_bytes(4, "little") + body


def test_renewals_larger_than_the_picture_or_not_webp_are_refused_before_decoding(monkeypatch):
    import cv2

    monkeypatch.setattr(cv2, "imdecode", lambda *a: pytest.fail("an image was decoded"))
    assert decode_renewal(webp_header_only(16000, 16000), (256, 256)) is None
    assert decode_renewal(b"\x89PNG\r\n\x1a\n" + bytes(20), (256, 256)) is None
    assert decode_renewal(b"", (256, 256)) is None


@pytest.mark.parametrize("body", [
    varint(3) + varint(0) + varint(1 << 30) + varint(0) + b"x",  # a renewal larger than any
    varint(3) + varint(0) + varint(10) + varint(8) + b"xyz",  # past its own end
    varint(3) + varint(7) + varint(1) + varint(0) + b"x",  # neither a residual nor a whole picture
    varint(3),  # ends inside its numbers
])
def test_absurd_picture_packets_are_damage_not_memory(face, call, body):
    chunks, _, _ = call
    stream = b"".join(chunks)
    hostile = stream[:len(chunks[0])] + build(PICTURE, body) * 200 + stream[len(chunks[0]):]
    tracemalloc.start()
    try:
        frames = list(facedeform.decode(hostile, face, size=(64, 64), on_damage=lambda line: None))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert len(frames) == 75 and peak < 64 << 20


def test_a_bomb_in_a_renewal_is_one_report_and_the_face_goes_on(face, call):
    chunks, _, _ = call
    stream = b"".join(chunks)
    bomb = webp_header_only(16000, 16000)
    hostile = stream[:len(chunks[0])] + build(PICTURE, varint(5) + varint(0) + varint(len(bomb)) + varint(0) + bomb) \
        + stream[len(chunks[0]):]
    reports = []
    frames = list(facedeform.decode(hostile, face, size=(64, 64), on_damage=reports.append))
    assert len(frames) == 75 and any("picture renewal at frame 5" in r for r in reports)


def test_a_stream_cut_inside_a_renewal_keeps_its_frames(face, call):
    chunks, _, _ = call
    stream = b"".join(chunks)
    cut = stream.index(bytes([SYNC, PICTURE << 5]), len(chunks[0])) + 5
    got = []
    with pytest.raises(facedeform.common.errors.BitstreamError, match="truncated"):
        for frame in facedeform.decode(stream[:cut], face, size=(64, 64)):
            got.append(frame)
    assert got  # the frames before it


def test_without_a_bitrate_or_with_the_layer_off_nothing_changes(face):
    plain = b"".join(facedeform.encode(CLIP, face))
    off = b"".join(facedeform.encode(CLIP, face, bitrate=RATE * 1000, picture_layer=False))
    for stream in (plain, off):
        decoder = StreamDecoder()
        assert not any(isinstance(e, Picture) for e in decoder.feed(stream) + decoder.close())


def test_over_datagrams_a_lost_renewal_is_made_good_by_the_next_whole_one(face):
    """A receiver that lost a renewal draws otherwise than the sender until the next whole renewal
    (one a second over datagrams), and then as it again, where the frame showed the scene."""
    with sender_pictures() as pictures:
        session = SendSession(str(CLIP), SendConfig(bitrate=RATE * 1000, embed_face=False, datagrams=True), face=face)
        datagrams = [d for packets in session.packets() for d in packets]
    decoder = DatagramDecoder()
    events = [e for d in datagrams for e in decoder.receive(d)]
    renewals = [e for e in events if isinstance(e, Picture)]
    wholes = [e.seq for e in renewals if e.whole]
    lost = next(e for e in renewals if not e.whole and e.seq < wholes[-1])
    view = PictureView(events[0], face.model, (360, 288))
    drawn = {}
    for event in events:
        if isinstance(event, Picture) and event is not lost:
            view.renew(event.seq, decode_renewal(event.data, view.picture_size), event.whole)
        elif isinstance(event, Frame):
            drawn[event.seq] = view.render(event.params, event.seq).copy()

    def psnr(seq):
        return 10 * np.log10(255 ** 2 / max(np.mean((drawn[seq].astype(float) - pictures[seq]) ** 2), 1e-10))

    resync = next(w for w in wholes if w > lost.seq)
    assert psnr(lost.seq) < 60 and psnr(resync - 1) < 60  # out of step from the lost renewal on
    assert psnr(resync) > psnr(resync - 1) + 3 and psnr(resync) > 35
