"""A paced face (fd-send --paced-face): the face model beside the frames within the rate, a preview first."""

import json

import numpy as np
import pytest

import facedeform
from facedeform.codec.face_file.format import decode_face, preview_face
from facedeform.common.errors import BitstreamError, InputError
from facedeform.protocol.framing import MODEL, PICTURE, SYNC, packet_type
from facedeform.protocol.report import Report
from facedeform.protocol.stream import DatagramDecoder, Frame, Model, StreamDecoder
from facedeform.receiver.session import ReceiveSession
from facedeform.sender.config import SendConfig
from facedeform.sender.session import SendSession
from facedeform.sender.sources import LoopedSource
from tests.support import CLIP, RECV, SEND, largest_window, run, sender_pictures, sent_per_frame

RATE = 30.0  # kbit/s: the sample's face (about 8.5 KB) is through in about 3 of the call's 12 s
SECONDS = 12.0


@pytest.fixture(scope="module")
def paced(face):
    """(stream chunks, bits of each frame's packets after the header, the sender's own picture of each
    frame its picture layer stepped) of the sample looped to SECONDS, its face paced at RATE."""
    with sender_pictures() as pictures:
        session = SendSession(LoopedSource(str(CLIP), SECONDS), SendConfig(bitrate=RATE * 1000, paced_face=True),
                              face=face)
        chunks, bits, _ = sent_per_frame(session)
        session.close()
    return chunks, bits, pictures


def faces_drawn(chunks: list[bytes], held=None) -> list[str]:
    """Per frame, which face the receiver drew it with (``held``: the face model it holds)."""
    kinds: list[str] = []
    session = ReceiveSession(lambda fps, size: [], None, held, warn=lambda line: None)
    decoder = StreamDecoder()
    for chunk in chunks:
        for event in decoder.feed(chunk):
            session.handle([event], 0.0)
            if isinstance(event, Frame):
                kinds.append(session.face_kind)
    return kinds


def test_the_call_starts_at_once_and_the_face_comes_within_the_rate(face, paced):
    chunks, bits, _ = paced
    assert len(chunks[0]) < 300  # the header alone
    kinds = faces_drawn(chunks)
    assert kinds[0] == "generic" and kinds[-1] == "stream"
    assert kinds == sorted(kinds, key=["generic", "preview", "stream"].index)  # each once, in that order
    preview, whole = kinds.index("preview"), kinds.index("stream")
    assert 0 < preview < whole < 0.6 * len(kinds)
    carried = len(preview_face(face.model)) + len(face.data)
    assert 8 * carried / (RATE * 1000) * 25 < whole  # no sooner than the rate allows...
    assert 8 * sum(map(len, chunks)) < 1.1 * RATE * 1000 * SECONDS  # ...and the call within it
    assert largest_window(bits) <= 1.1 * RATE * 1000


def test_a_receiver_that_holds_the_face_draws_it_from_the_start(face, paced):
    chunks, _, _ = paced
    assert set(faces_drawn(chunks, face.model)) == {"file"}


def test_the_picture_layer_follows_the_face_bit_for_bit(paced):
    """The layer starts once the face is through; the receiver draws what the sender reconstructs."""
    chunks, _, pictures = paced
    drawn = list(facedeform.decode(chunks))
    whole = faces_drawn(chunks).index("stream")
    assert 0 < len(pictures) <= len(drawn) - whole - 25  # seconds after the face is through
    for got, want in zip(drawn[-len(pictures):], pictures, strict=True):
        np.testing.assert_array_equal(got, want)


def test_a_preview_is_the_face_coarser_and_still(face):
    """The preview draws the whole picture (the same size, mesh and placement, a coarser picture)
    without the motion basis, open mouth or shut eyes."""
    model = face.model
    preview = decode_face(preview_face(model))
    assert preview.motion is None and preview.picture.mouth is None and preview.picture.shut_eyes is None
    assert preview.picture.image.shape == model.picture.image.shape
    np.testing.assert_allclose(preview.picture.projection, model.picture.projection)
    assert np.abs(preview.vertices - model.vertices).max() <= 0.5 / 256 + 1e-9  # within 1/512 of the face's height
    error = np.abs(preview.picture.image.astype(int) - model.picture.image).mean()
    assert 0 < error < 8


def test_a_call_cut_before_its_face_came_keeps_its_frames(paced):
    chunks, _, _ = paced
    kinds = faces_drawn(chunks)
    cut = kinds.index("preview") + 5  # frames drawn with the preview, the face not yet whole
    stream = b"".join(chunks[:cut])
    got = []
    with pytest.raises(BitstreamError, match="truncated"):
        for image in facedeform.decode(stream):
            got.append(image)
    events = StreamDecoder().feed(stream)
    assert len(got) == sum(isinstance(e, Frame) for e in events) > 0
    assert [e.preview for e in events if isinstance(e, Model)] == [True]


@pytest.mark.parametrize("options, message", [
    ({"paced_face": True}, "within a --bitrate"),
    ({"paced_face": True, "bitrate": 4000, "embed_face": False}, "not with --face-by-id"),
])
def test_a_paced_face_needs_a_rate_and_the_face_in_the_stream(options, message):
    with pytest.raises(InputError, match=message):
        SendConfig(**options)


def test_fd_recv_says_when_a_call_ended_before_its_face_came(face, tmp_path):
    """The sample's 3 s at 4 kbit/s bring the preview, not the face: the frames are all written, and
    fd-recv says with what they were drawn."""
    face.save(tmp_path / "me.fdface")
    sent = run(SEND + [str(CLIP), "--face", str(tmp_path / "me.fdface"), "--paced-face", "--bitrate", "4"])
    assert sent.returncode == 0, sent.stderr.decode()
    got = run(RECV + ["-", "-o", str(tmp_path / "out.y4m"), "--json"], stdin=sent.stdout)
    assert got.returncode == 0, got.stderr.decode()
    lines = got.stderr.decode().splitlines()
    assert sum("ended before its face model had come whole" in line for line in lines) == 1
    stats = json.loads(lines[-1])
    assert stats["written"] == 75 and stats["face"] in ("generic", "preview")


def test_fd_send_says_what_a_paced_face_goes_with(tmp_path):
    for extra, message in ((["--paced-face", "--bitrate", "4"], b"--paced-face goes with --face"),
                           (["--paced-face", "--face", str(tmp_path / "x.fdface")], b"goes with --bitrate")):
        result = run(SEND + [str(CLIP)] + extra)
        assert result.returncode == 2 and message in result.stderr and b"Traceback" not in result.stderr


def kind(datagram: bytes) -> int | None:
    """MODEL, PICTURE... of a datagram that is one packet of its own; None for frames datagrams."""
    return packet_type(datagram[1]) if datagram[0] == SYNC and len(datagram) > 1 else None


def udp_call(face, lose=(), join=0, reports=True, held=False) -> tuple[list[list[bytes]], list, DatagramDecoder]:
    """The sample looped to SECONDS with its face paced at RATE over datagrams, to a receiver that loses
    the datagrams whose indices are in ``lose``, hears none before the ``join``-th, holds the face
    already if ``held`` and, with ``reports``, reports back after every frame as fd-recv does every
    half second: (the datagrams of each step, the receiver's events, its decoder)."""
    session = SendSession(LoopedSource(str(CLIP), SECONDS),
                          SendConfig(bitrate=RATE * 1000, paced_face=True, datagrams=True), face=face)
    decoder, events, count = DatagramDecoder(), [], [0]
    if held:
        decoder.hold_model()
    if reports:
        session.feedback = lambda: Report(count[0], decoder.stats.repaired, decoder.stats.concealed,
                                          decoder.model_missing) if count[0] > join else None
    steps = []
    for datagrams in session.packets():
        steps.append(datagrams)
        for datagram in datagrams:
            if count[0] >= join and count[0] not in lose:
                events += decoder.receive(datagram)
            count[0] += 1
    session.close()
    return steps, events, decoder


def test_over_udp_a_lost_chunk_comes_again_and_the_layer_starts_once_the_receiver_holds_the_face(face):
    steps, _, _ = udp_call(face)
    flat = [d for step in steps for d in step]
    chunks = [i for i, d in enumerate(flat) if kind(d) == MODEL]
    steps, events, decoder = udp_call(face, lose={chunks[3]})
    whole = [e.data for e in events if isinstance(e, Model) and not e.preview]
    assert whole == [face.data] and decoder.model_missing == len(preview_face(face.model)) + len(face.data)
    flat = [d for step in steps for d in step]
    sent = [i for i, d in enumerate(flat) if kind(d) == MODEL]
    assert len(sent) > len(chunks)  # the lost chunk again, and no more rounds once it is held
    assert len(sent) < 2 * len(chunks)
    layer = [i for i, d in enumerate(flat) if kind(d) == PICTURE]
    assert layer and layer[0] > sent[-1]  # the layer after the face, which the receiver then holds
    frames = [e for e in events if isinstance(e, Frame)]
    assert len(frames) == round(SECONDS * 25) and not any(f.concealed for f in frames)


def test_over_udp_a_receiver_that_joins_late_gets_the_face_in_the_next_round(face):
    """Without reports (a one-way link) the face goes round the whole call; a receiver that joins after
    the first round has the header from its repeats and the face from a later round."""
    steps, _, _ = udp_call(face, reports=False)
    flat = [d for step in steps for d in step]
    chunks = [i for i, d in enumerate(flat) if kind(d) == MODEL]
    first_round = next(i for i, c in enumerate(chunks) if i and flat[c] == flat[chunks[0]])  # the first again
    assert not any(kind(d) == PICTURE for d in flat)  # no layer while the face may be lacking
    _, events, decoder = udp_call(face, join=chunks[first_round - 1] + 1, reports=False)
    assert [e.data for e in events if isinstance(e, Model) and not e.preview] == [face.data]


def test_over_udp_a_receiver_that_holds_the_face_stops_it_at_its_first_report(face):
    steps, events, _ = udp_call(face, held=True)
    flat = [d for step in steps for d in step]
    sent = [i for i, d in enumerate(flat) if kind(d) == MODEL]
    assert len(sent) <= 2 and not any(isinstance(e, Model) for e in events)  # the first frame's chunks at most
    assert any(kind(d) == PICTURE for d in flat)
