"""The stream format: round trip, any chunking, and nothing but BitstreamError on bad bytes."""

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from codec.errors import BitstreamError
from protocol.quantise import dequantise, quantise, steps_for
from protocol.stream import End, Frame, Header, StreamDecoder, encode_end, encode_frame, encode_header

NAMES = ("theta", "v2x", "v2y", "v2z", "rx")
HEADER = Header(25.0, NAMES, steps_for(NAMES), "ab" * 32)


def make_stream(params: np.ndarray, faces=None) -> bytes:
    faces = [True] * len(params) if faces is None else faces
    body = b"".join(encode_frame(HEADER, i, p, f) for i, (p, f) in enumerate(zip(params, faces)))
    return encode_header(HEADER) + body + encode_end(len(params))


def decode_all(data: bytes, chunk: int | None = None) -> list:
    decoder = StreamDecoder()
    chunks = [data] if chunk is None else [data[i:i + chunk] for i in range(0, len(data), chunk)]
    events = [e for c in chunks for e in decoder.feed(c)]
    decoder.close()
    return events


values = st.lists(st.lists(st.floats(-30, 30), min_size=len(NAMES), max_size=len(NAMES)), max_size=20)


@settings(max_examples=50, deadline=None)
@given(values)
def test_round_trip_gives_the_quantised_values(rows):
    params = np.array(rows, dtype=np.float64).reshape(-1, len(NAMES))
    events = decode_all(make_stream(params))
    assert isinstance(events[0], Header) and events[0].names == NAMES
    frames = [e for e in events if isinstance(e, Frame)]
    assert [f.seq for f in frames] == list(range(len(params)))
    for f, p in zip(frames, params):
        np.testing.assert_array_equal(f.params, dequantise(quantise(p, HEADER.steps), HEADER.steps))
    assert events[-1] == End(len(params))


def test_quantisation_error_is_at_most_half_a_step():
    rng = np.random.default_rng(1)
    p = rng.uniform(-1, 1, size=len(NAMES))
    err = np.abs(dequantise(quantise(p, HEADER.steps), HEADER.steps) - p)
    assert np.all(err <= HEADER.steps / 2 + 1e-12)


def test_byte_by_byte_equals_whole():
    params = np.random.default_rng(0).normal(size=(8, len(NAMES)))
    data = make_stream(params, faces=[True, False] * 4)
    whole, single = decode_all(data), decode_all(data, chunk=1)
    assert len(whole) == len(single) == 10
    for a, b in zip(whole[1:-1], single[1:-1]):
        assert (a.seq, a.face_seen) == (b.seq, b.face_seen)
        np.testing.assert_array_equal(a.params, b.params)
    assert [f.face_seen for f in whole[1:-1]] == [True, False] * 4


def test_every_truncated_prefix_fails_cleanly_and_keeps_its_frames():
    data = make_stream(np.zeros((3, len(NAMES))))
    for cut in range(len(data)):
        decoder = StreamDecoder()
        events = decoder.feed(data[:cut])
        assert all(isinstance(e, (Header, Frame)) for e in events)
        with pytest.raises(BitstreamError):
            decoder.close()


def test_missing_frames_are_concealed_with_the_last_one():
    p = np.ones((1, len(NAMES)))
    data = encode_header(HEADER) + encode_frame(HEADER, 0, p[0], True) + encode_frame(HEADER, 3, 2 * p[0], True)
    frames = StreamDecoder().feed(data)[1:]
    assert [(f.seq, f.concealed) for f in frames] == [(0, False), (1, True), (2, True), (3, False)]
    np.testing.assert_array_equal(frames[1].params, frames[0].params)


@pytest.mark.parametrize("data, message", [
    (b"", "empty input"),
    (b"hello, this is not a stream", "not an fd stream"),
    (msgpack.packb({"fd": "fdcodec", "v": 99}), "unsupported stream version 99"),
    (msgpack.packb({"fd": "fdcodec", "v": 1, "fps": 25.0}), "corrupted stream header"),
    (encode_header(HEADER) + msgpack.packb([0, 1, [1, 2]]), "malformed frame packet"),
    (encode_header(HEADER) + encode_frame(HEADER, 2, np.zeros(5), True) + encode_frame(HEADER, 1, np.zeros(5), True),
     "frame 1 after frame 2"),
    (encode_header(HEADER) + encode_end(0) + b"x", "data after the end"),
])
def test_bad_streams_raise_bitstream_error(data, message):
    decoder = StreamDecoder()
    with pytest.raises(BitstreamError, match=message):
        decoder.feed(data)
        decoder.close()


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200), st.integers(0, 400))
def test_fuzz_only_bitstream_error_escapes(junk, position):
    data = make_stream(np.zeros((2, len(NAMES))))
    position = min(position, len(data))
    decoder = StreamDecoder()
    try:
        decoder.feed(data[:position] + junk + data[position:])
        decoder.close()
    except BitstreamError:
        pass
