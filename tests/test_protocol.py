"""The stream format: exact round trip, any chunking, survival of damage, bounded refusal of hostile input."""

from dataclasses import replace
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from facedeform.common.errors import BitstreamError, FdError
from facedeform.common.limits import MAX_SIDE
from facedeform.common.parameters import LAYOUTS as NAMED
from facedeform.common.parameters import PAPER_PARAMS
from facedeform.protocol.basis import SCALE
from facedeform.protocol.framing import END, HEADER, SYNC, Delta, build, read_varint, varint
from facedeform.protocol.header import MAX_AHEAD, MAX_MODEL, VERSION, encode_header, parse_header
from facedeform.protocol.layouts import shipped, shipped_basis
from facedeform.protocol.quantise import QUALITIES, dequantise, hold_or_round, quantise
from facedeform.protocol.stream import (
    Damage,
    DatagramDecoder,
    End,
    Frame,
    Header,
    Model,
    PacketEncoder,
    StreamDecoder,
    frame_bytes,
    steps_for,
)

LAYOUTS = (PAPER_PARAMS, PAPER_PARAMS + ("rx", "ry", "rz"))
FACE = "ab" * 32


def header(names=PAPER_PARAMS, quality=3, **kw) -> Header:
    return Header(25.0, names, steps_for(names, quality), FACE, quality=quality, **kw)


#: A header whose steps are no quality level's: they are written out.
CUSTOM = Header(25.0, PAPER_PARAMS, steps_for(PAPER_PARAMS) * 1.5, FACE, quality=0)


def random_basis(k: int, seed: int = 0) -> np.ndarray:
    """(k, k) int8 coding basis: a random rotation, rounded as the header carries it."""
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(k, k)))
    return np.rint(q * SCALE).astype(np.int8)


def walk(n: int, k: int, seed: int = 0) -> np.ndarray:
    """(n, k) smooth random-walk parameters in the dev clips' range."""
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.normal(0, 0.004, (n, k)), axis=0)


def encode(h: Header, params: np.ndarray, fpp: int = 1, faces=None, model=b"", dead_zone=0.5,
           sent=None) -> list[bytes]:
    """The stream's packets, plain rounding unless a ``dead_zone`` is given; ``sent`` (a list) receives the
    encoder's reconstruction of each coded frame."""
    enc = PacketEncoder(h, fpp, model, dead_zone)
    faces = [True] * len(params) if faces is None else faces
    packets = enc.header()
    for i, (x, f) in enumerate(zip(params, faces)):
        packets += enc.frame(x, f)
        if sent is not None and i % h.divisor == 0:
            sent.append(enc.reconstruction)
    return packets + enc.end()


def decode(data: bytes, chunk: int | None = None) -> tuple[list, StreamDecoder]:
    dec = StreamDecoder()
    chunks = [data] if chunk is None else [data[i:i + chunk] for i in range(0, len(data), chunk)]
    return [e for c in chunks for e in dec.feed(c)] + dec.close(), dec


def frames(events) -> list[Frame]:
    return [e for e in events if isinstance(e, Frame)]


@settings(max_examples=40, deadline=None)
@given(st.sampled_from(LAYOUTS), st.sampled_from(QUALITIES), st.integers(1, 32), st.booleans(),
       st.integers(1, 30), st.lists(st.floats(-2, 2), min_size=0, max_size=60), st.integers(0, 2**32 - 1),
       st.booleans())
def test_round_trip_gives_the_quantised_values(names, quality, fpp, static, key, jumps, seed, basis):
    h = header(names, quality, skip_static=static, key_interval=key,
               basis=random_basis(len(names), seed) if basis else None)
    params = walk(len(jumps), len(names), seed) + np.array(jumps)[:, None]
    params[1::3] = params[0::3][:len(params[1::3])]  # static runs
    faces = [bool(i % 5) for i in range(len(params))]
    events, dec = decode(frame_bytes(encode(h, params, fpp, faces)))
    assert events[0] == h and events[-1] == End(len(params)) and not dec.stats.damaged
    got = frames(events)
    assert [f.seq for f in got] == list(range(len(params)))
    for f, x, face in zip(got, params, faces):
        np.testing.assert_array_equal(f.params, h.values(quantise(h.coordinates(x), 1.0)))
        assert f.face_seen == face and not f.concealed
        if not basis:
            np.testing.assert_array_equal(f.params, dequantise(quantise(x, h.steps), h.steps))


@settings(max_examples=40, deadline=None)
@given(st.sampled_from(LAYOUTS), st.sampled_from(QUALITIES), st.floats(0.5, 4), st.integers(1, 32), st.booleans(),
       st.integers(1, 30), st.integers(1, 4), st.lists(st.floats(-2, 2), min_size=0, max_size=60),
       st.integers(0, 2**32 - 1), st.booleans())
def test_decoder_outputs_the_encoders_reconstruction_within_the_dead_zone(
        names, quality, dead_zone, fpp, static, key, divisor, jumps, seed, basis):
    h = header(names, quality, skip_static=static, key_interval=key, divisor=divisor,
               basis=random_basis(len(names), seed) if basis else None)
    params = walk(len(jumps), len(names), seed) + np.array(jumps)[:, None]
    params[1::3] = params[0::3][:len(params[1::3])]
    sent: list[np.ndarray] = []
    events, dec = decode(frame_bytes(encode(h, params, fpp, dead_zone=dead_zone, sent=sent)))
    got = frames(events)
    assert [f.seq for f in got] == list(range(len(params))) and not dec.stats.damaged
    coded = [f for f in got if f.seq % divisor == 0]
    assert len(coded) == len(sent) and not any(f.interpolated for f in coded)
    for f, r in zip(coded, sent):
        np.testing.assert_array_equal(f.params, r)
        error = np.abs(h.coordinates(r) - h.coordinates(params[f.seq]))  # in steps along the coded axes
        assert np.all(error <= max(dead_zone, 0.5) * (1 + 1e-9))


@settings(max_examples=30, deadline=None)
@given(st.sampled_from(LAYOUTS), st.integers(1, 8), st.integers(1, 30),
       st.dictionaries(st.integers(0, 59), st.sampled_from(QUALITIES), max_size=4), st.integers(0, 2**32 - 1),
       st.booleans(), st.booleans())
@example(LAYOUTS[0], 7, 27, {1: 1, 28: 2}, 0, False, True)  # the last level's keyframe goes with the end mark
def test_a_new_level_mid_stream_goes_from_a_keyframe_and_decodes_to_the_encoders_reconstruction(
        names, fpp, key, changes, seed, basis, at_place):
    """PacketEncoder.relevel: the frame after it (or, ``at_place``, the next key place) is a keyframe
    naming the header at the new level (Header.levels), the packet before it ended there; the decoder
    outputs exactly what the encoder reconstructed, within the dead zone of each frame's own level's steps."""
    h = header(names, 3, key_interval=key, basis=random_basis(len(names), seed) if basis else None)
    params = walk(60, len(names), seed) * 8
    enc, sent = PacketEncoder(h, fpp, dead_zone=1.0), []
    packets = enc.header()
    for i, x in enumerate(params):
        if i in changes:
            enc.relevel(changes[i], at_place)
        packets += enc.frame(x, True)
        sent.append((enc.reconstruction, enc.level))
    packets += enc.end()  # (the last new level's keyframe may still be pending: it goes with the end mark)
    events, dec = decode(frame_bytes(packets))
    got = frames(events)
    assert events[0] == h and not dec.stats.damaged and [f.seq for f in got] == list(range(60))
    for f, x, (r, level) in zip(got, params, sent):
        np.testing.assert_array_equal(f.params, r)
        steps = h.at_level(level)
        assert np.all(np.abs(steps.coordinates(r) - steps.coordinates(x)) <= 1 + 1e-9)
    keys = [read_varint(p, 6, 1 << 20)[0] for p in packets if p[:1] == bytes([SYNC]) and p[2:6] in h.levels]
    assert len(keys) >= len({level for _, level in sent}) and len(h.levels) == len(QUALITIES)
    assert not at_place or all(k % key == 0 for k in keys)


def test_a_keyframe_at_another_level_of_a_held_header_starts_a_late_joiner():
    """A receiver that holds the stream's header (an earlier call) starts at a keyframe naming it at any
    of its levels; a keyframe naming none of them (another stream's) is not taken."""
    h = header(PAPER_PARAMS, 3)
    enc = PacketEncoder(h)
    for x in walk(7, len(PAPER_PARAMS)):
        enc.frame(x, True)
    enc.relevel(1)
    key = enc.frame(np.zeros(len(PAPER_PARAMS)), True)
    late = DatagramDecoder(known=[h])
    started = [e for p in key for e in late.receive(p)]
    assert started[0] == h and [f.seq for f in frames(started)] == [7]
    stranger = DatagramDecoder(known=[header(PAPER_PARAMS, 3, key_interval=24)])
    assert not [e for p in key for e in stranger.receive(p)]


def test_a_header_with_steps_of_its_own_has_no_other_level():
    assert list(CUSTOM.levels.values()) == [CUSTOM]
    with pytest.raises(ValueError, match="no quality level"):
        CUSTOM.at_level(3)


@given(st.lists(st.floats(-1, 1), min_size=1, max_size=40), st.floats(0.5, 4))
def test_dead_zone_holds_what_the_decoder_has_until_the_value_leaves_it(track, dead_zone):
    steps = np.array([0.01])
    held = None
    for x in track:
        index = hold_or_round(np.array([x]), steps, held, dead_zone)
        nearest = quantise(np.array([x]), steps)
        if held is not None and abs(x / steps[0] - held[0]) < dead_zone:
            assert index == held
        else:
            assert index == nearest
        held = index


@given(st.lists(st.floats(-1, 1), min_size=2, max_size=40))
def test_half_step_dead_zone_is_plain_rounding(track):
    steps = np.array([0.01])
    held = None
    for x in track:
        held = hold_or_round(np.array([x]), steps, held, 0.5)
        assert held == quantise(np.array([x]), steps)


def test_dead_zone_keeps_a_jittering_value_still_and_costs_fewer_bits():
    h = header()
    rng = np.random.default_rng(1)
    still = np.arange(13) * h.steps  # on the quantiser's grid: the first frame holds it exactly
    params = still + rng.uniform(-0.95, 0.95, (100, 13)) * h.steps
    params[0] = still
    sent: list[np.ndarray] = []
    held = frame_bytes(encode(h, params, 4, dead_zone=1.0, sent=sent)[1:])  # after the header
    assert all(np.array_equal(r, still) for r in sent)
    assert len(held) < len(frame_bytes(encode(h, params, 4)[1:])) / 2


def test_the_rounded_parameters_keep_to_half_a_step_at_the_encoders_dead_zone():
    """fd-send's head pose over a reference picture: the other parameters are held within the dead
    zone of 3 steps, the rotation's within half a step of every frame's value, and the decoder outputs
    what the encoder reconstructed."""
    names = LAYOUTS[1]
    h = header(names)
    rotation = [names.index(n) for n in ("rx", "ry", "rz")]
    params = walk(100, len(names))
    params[:, rotation] *= 60  # about a step a frame, as a turning head's
    enc = PacketEncoder(h, 2, dead_zone=3.0, rounded=("rx", "ry", "rz"))
    packets, sent = enc.header(), []
    for x in params:
        packets += enc.frame(x, True)
        sent.append(enc.reconstruction)
    events, dec = decode(frame_bytes(packets + enc.end()))
    got = [e for e in events if isinstance(e, Frame)]
    error = np.abs(np.array(sent) - params) / h.steps
    assert np.all(error[:, rotation] <= 0.5 + 1e-9) and error.max() > 1.0  # the others held further
    assert len(got) == len(params) and not dec.stats.damaged
    for f, r in zip(got, sent):
        np.testing.assert_array_equal(f.params, r)


def test_the_rounded_parameters_are_held_by_as_much_as_the_dead_zone_is_widened():
    """A rate keeper widening the dead zone from 1 step to 3 (a rate the coarsest level does not fit)
    holds the rounded parameters within 2.5 steps: the keeper's lever stays theirs too."""
    names = LAYOUTS[1]
    rotation = [names.index(n) for n in ("rx", "ry", "rz")]
    params = walk(100, len(names))
    params[:, rotation] *= 60
    enc = PacketEncoder(header(names), 2, dead_zone=1.0, rounded=("rx", "ry", "rz"))
    enc.header()
    enc.dead_zone = 3.0
    sent = []
    for x in params:
        enc.frame(x, True)
        sent.append(enc.reconstruction)
    error = np.abs(np.array(sent) - params)[:, rotation] / header(names).steps[rotation]
    assert 0.5 < error.max() <= 2.5 + 1e-9


def test_only_placing_parameters_are_rounded_apart():
    """A coding basis mixes the other parameters' coordinates; the placing ones it keeps on axes of their own."""
    with pytest.raises(ValueError, match="placing"):
        PacketEncoder(header(), 1, rounded=("theta",))


def test_dead_zone_out_of_range_is_refused():
    for bad in (0.4, 4.5, float("nan")):
        with pytest.raises(BitstreamError, match="dead zone"):
            PacketEncoder(header(), 1, dead_zone=bad)


def test_datagrams_decode_like_the_byte_stream():
    h = header()
    packets = encode(h, walk(60, 13), fpp=3)
    dec = DatagramDecoder()
    from_datagrams = [e for p in packets for e in dec.receive(p)]
    from_stream, _ = decode(frame_bytes(packets))
    assert len(frames(from_datagrams)) == 60
    for a, b in zip(frames(from_datagrams), frames(from_stream)):
        np.testing.assert_array_equal(a.params, b.params)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 12), st.integers(1, 9), st.lists(st.floats(-2, 2), min_size=1, max_size=40),
       st.integers(0, 2**32 - 1), st.lists(st.integers(1, 9), min_size=1, max_size=8))
def test_any_chunking_gives_the_frames_of_the_whole(fpp, key, jumps, seed, chunks):
    """A packet is read as soon as its last byte is in, whatever follows it or not yet."""
    params = walk(len(jumps), 13, seed) + np.array(jumps)[:, None]
    params[1::4] = params[0::4][:len(params[1::4])]
    data = frame_bytes(encode(header(skip_static=True, key_interval=key), params, fpp))
    whole, _ = decode(data)
    dec, parts, pos = StreamDecoder(), [], 0
    for i in range(len(data)):
        n = chunks[i % len(chunks)]
        parts += dec.feed(data[pos:pos + n])
        pos += n
        if pos >= len(data):
            break
    parts += dec.close()
    assert [type(e) for e in parts] == [type(e) for e in whole] and not dec.stats.damaged
    for a, b in zip(frames(whole), frames(parts)):
        np.testing.assert_array_equal(a.params, b.params)


def test_byte_by_byte_equals_whole():
    data = frame_bytes(encode(header(skip_static=True), walk(50, 13), fpp=4))
    whole, _ = decode(data)
    single, _ = decode(data, chunk=1)
    assert [type(e) for e in whole] == [type(e) for e in single]
    for a, b in zip(frames(whole), frames(single)):
        assert (a.seq, a.face_seen) == (b.seq, b.face_seen)
        np.testing.assert_array_equal(a.params, b.params)


GOLDEN_PARAMS = np.array([[0.0, 0.0], [0.5, 0.004], [0.5, 0.004], [1.0, -0.01], [1.0, 0.0]])
GOLDEN = Path(__file__).with_name("fixtures") / f"golden_v{VERSION}.fd"


def golden_header() -> Header:
    return Header(25.0, ("theta", "v2x"), steps_for(("theta", "v2x")), FACE, key_interval=4, skip_static=True,
                  width=640, height=480)


def test_golden_stream_bytes_are_stable():
    """Fixed input, fixed bytes: a change here is a format change and needs a new version."""
    assert frame_bytes(encode(golden_header(), GOLDEN_PARAMS)) == GOLDEN.read_bytes()


def test_the_golden_stream_decodes_and_codes_back_to_itself():
    """serialize(parse(x)) == x: the header and the decoded frames, coded again, give the same bytes,
    whole and fed a byte at a time."""
    data = GOLDEN.read_bytes()
    for chunk in (None, 1):
        events, dec = decode(data, chunk)
        assert events[0] == golden_header() and events[-1] == End(len(GOLDEN_PARAMS)) and not dec.stats.damaged
        decoded = np.array([f.params for f in frames(events)])
        np.testing.assert_array_equal(decoded, GOLDEN_PARAMS)
        assert frame_bytes(encode(dec.header, decoded)) == data
    body = encode_header(golden_header())
    assert encode_header(parse_header(body)) == body


def test_deltas_end_themselves():
    """No length, no sync byte, never the sync byte first; every other packet starts with its sync
    byte, in datagrams too, so a byte stream is the packets end to end."""
    packets = encode(header(skip_static=True), walk(60, 13), fpp=2)
    deltas = [p for p in packets if isinstance(p, Delta)]
    assert len(deltas) > 20 and all(p[0] != SYNC for p in deltas)
    assert all(p[0] == SYNC for p in packets if not isinstance(p, Delta))
    assert frame_bytes(packets) == b"".join(packets)


@pytest.mark.parametrize("golden", [False, True])
def test_every_truncated_prefix_keeps_its_frames_and_reports_the_cut(golden):
    data = GOLDEN.read_bytes() if golden else frame_bytes(encode(header(), walk(6, 13)))
    full = frames(decode(data)[0])
    header_end = len(encode(golden_header() if golden else header(), walk(0, 13))[0])
    for cut in range(len(data)):
        dec = StreamDecoder()
        if cut < header_end:
            dec.feed(data[:cut])
            with pytest.raises(BitstreamError):
                dec.close()
            continue
        events = dec.feed(data[:cut]) + dec.close()
        got = [f for f in frames(events) if not f.concealed]
        assert [f.seq for f in got] == [f.seq for f in full[:len(got)]]
        assert isinstance(events[-1], Damage) and not dec.ended


@pytest.mark.parametrize("damage", ["flip", "drop", "duplicate"])
def test_damage_is_concealed_until_the_next_keyframe(damage):
    h = header(key_interval=10)
    params = walk(40, 13)
    packets = encode(h, params)  # header, 40 frame packets, end
    victim = 1 + 13  # frame 13, in the second group
    if damage == "flip":
        packets[victim] = packets[victim][:-1] + bytes([packets[victim][-1] ^ 0x10])
    elif damage == "drop":
        del packets[victim]
    else:
        packets.insert(victim, packets[victim])
    events, dec = decode(frame_bytes(packets))
    got = frames(events)
    assert [f.seq for f in got] == list(range(40)) and events[-1] == End(40)
    concealed = [f.seq for f in got if f.concealed]
    if damage == "duplicate":
        assert concealed == [] and dec.stats.duplicates == 1
    else:
        assert concealed == list(range(13, 20)) and dec.stats.damaged == 1
        assert [e.seq for e in events if isinstance(e, Damage)] == [13]
    for f in got[:13] + got[20:]:
        np.testing.assert_array_equal(f.params, dequantise(quantise(params[f.seq], h.steps), h.steps))


def test_damage_to_a_delta_of_many_frames_is_concealed_until_the_next_keyframe():
    params = walk(40, 13)
    packets = encode(header(key_interval=20), params, fpp=8)  # header, key 0-7, deltas 8-15 and 16-19, key 20-27...
    assert isinstance(packets[2], Delta)
    packets[2] = packets[2][:-1] + bytes([packets[2][-1] ^ 0x01])
    events, dec = decode(frame_bytes(packets))
    got = frames(events)
    assert [f.seq for f in got if f.concealed] == list(range(8, 20)) and dec.stats.damaged == 1
    assert [f.seq for f in got] == list(range(40)) and events[-1] == End(40)


def test_divisor_interpolates_between_sent_frames():
    h = header(divisor=3)
    params = np.linspace(0, 0.3, 10)[:, None] * np.ones(13)
    got = frames(decode(frame_bytes(encode(h, params)))[0])
    assert [f.seq for f in got] == list(range(10))
    assert [f.interpolated for f in got] == [False, True, True] * 3 + [False]
    np.testing.assert_allclose(got[4].params, params[4], atol=h.steps.max())


def test_face_model_travels_after_the_header():
    model = bytes(range(256)) * 9
    h = header(model_size=len(model))
    events, _ = decode(frame_bytes(encode(h, walk(3, 13), model=model)), chunk=7)
    assert [e.data for e in events if isinstance(e, Model)] == [model]


def test_a_preview_face_comes_first_and_the_model_between_frames():
    """A paced face (sender/face_pacing.py): the model's chunks between frames, of any size; the
    preview is handed over once its bytes are in (the chunk that completes it runs on into the
    model), the model once it is whole, each between the frames the chunks came between."""
    preview, model = bytes(range(256)) * 3, bytes(range(255, -1, -1)) * 12
    h = header(model_size=len(preview) + len(model), preview_size=len(preview))
    assert parse_header(encode_header(h)) == h and parse_header(encode_header(h)).preview_size == len(preview)
    enc = PacketEncoder(h, model=preview + model)
    packets, offset = enc.header(model=False), 0
    for size, x in zip([500, 600, 1024, 1024, 1000, 100], walk(6, 13)):
        packets += enc.frame(x, True)
        if offset < h.model_size:
            packets.append(enc.model_chunk(offset, size))
            offset += size
    events, dec = decode(frame_bytes(packets + enc.end()), chunk=11)
    kinds = [("preview" if e.preview else "model", e.data) if isinstance(e, Model) else type(e).__name__
             for e in events if not isinstance(e, Header)]
    assert kinds == ["Frame", "Frame", ("preview", preview), "Frame", "Frame", "Frame", ("model", model),
                     "Frame", "End"]
    assert not dec.stats.damaged


def test_a_face_going_round_is_taken_in_any_order():
    """Over datagrams a paced face goes round (sender/face_pacing.py): a receiver that joined late, or
    lost a chunk, takes the model's chunks from anywhere in it, some twice; the preview and the model
    are each handed over once, as soon as they are whole."""
    preview, model = bytes(range(256)) * 3, bytes(range(255, -1, -1)) * 12
    size = len(preview) + len(model)
    h = header(model_size=size, preview_size=len(preview))
    enc = PacketEncoder(h, model=preview + model)
    offsets = list(range(1500, size, 500)) + list(range(0, size, 500))  # joined in the first round's middle
    packets = enc.header(model=False)
    for offset, x in zip(offsets, walk(len(offsets), 13)):
        packets += enc.frame(x, True) + [enc.model_chunk(offset, min(500, size - offset))]
    events, dec = decode(frame_bytes(packets + enc.end()), chunk=11)
    models = [(e.preview, e.data) for e in events if isinstance(e, Model)]
    assert models == [(True, preview), (False, model)] and dec.model_missing == size
    assert dec.stats.duplicates == 5 and not dec.stats.damaged  # the five chunks from 1500 on came twice


def test_a_preview_must_be_part_of_the_model():
    for model_size, preview_size in ((100, 100), (0, 10), (100, 200)):
        with pytest.raises(ValueError, match="out of range"):
            header(model_size=model_size, preview_size=preview_size)
    h = header(model_size=100, preview_size=60)
    body = encode_header(h)
    at = body.index(varint(100) + varint(60)) + 1  # the preview's size, made the model's
    with pytest.raises(BitstreamError, match="out of range"):
        StreamDecoder().feed(build(HEADER, body[:at] + varint(100) + body[at + 1:]))
    with pytest.raises(BitstreamError, match="a preview of 0 bytes"):
        StreamDecoder().feed(build(HEADER, body[:at] + varint(0) + body[at + 1:]))


@pytest.mark.parametrize("data, message", [
    (b"", "empty input"),
    (b"hello, this is not a stream", "not an fd stream"),
    (bytes(70000), "not an fd stream"),
    (build(HEADER, b"FD\x63" + bytes(40)), f"unsupported stream version 99 \\(this decoder reads version {VERSION}\\)"),
    (build(HEADER, b"FD\x06" + bytes(40)), "unsupported stream version 6"),
    (build(HEADER, encode_header(CUSTOM)[:-3]), "header length"),
])
def test_foreign_input_raises_bitstream_error(data, message):
    dec = StreamDecoder()
    with pytest.raises(BitstreamError, match=message):
        dec.feed(data)
        dec.close()


def test_a_layout_every_package_holds_is_named_by_one_byte():
    for names, basis in shipped():
        h = Header(25.0, names, steps_for(names), FACE, basis=basis.copy(), skip_static=True)
        body = encode_header(h)
        assert len(body) < 64 and parse_header(body) == h
        np.testing.assert_array_equal(parse_header(body).basis, basis)
        other = basis.copy()
        other[[0, 1]] = other[[1, 0]]  # the same names with another basis: written out
        assert len(encode_header(replace(h, basis=other))) > len(names) ** 2
        assert parse_header(encode_header(replace(h, basis=other))) == replace(h, basis=other)
    mouth = next(names for names, _ in shipped() if len(names) == 39)
    assert len(encode_header(Header(25.0, mouth, steps_for(mouth), FACE, basis=shipped_basis(mouth)))) <= 64


def test_hostile_header_is_refused_before_allocation():
    body = bytearray(encode_header(header()))
    model_at = 2 + 6 + len(varint(25000)) + 2 + 32  # magic, version and five bytes, fps, width, height, face id
    body[model_at:model_at + 1] = b"\xff\xff\xff\xff\x0f"  # model size 2**32 - 1
    with pytest.raises(BitstreamError, match="over its limit"):
        StreamDecoder().feed(build(HEADER, bytes(body)))
    assert MAX_MODEL < 2**32 - 1
    dec = StreamDecoder()  # a length field over the packet limit is skipped, not waited for
    events = dec.feed(frame_bytes(encode(header(), walk(1, 13))[:1]) + b"\xfd\x80\xff\xff\xff\xff\x0f")
    assert dec.stats.skipped_bytes > 0 and len(events) == 2 and events[1].reason.startswith("packet fails")


@cache
def fuzz_packets(fpp: int) -> list[bytes]:
    basis = random_basis(13) if fpp % 2 else None  # the header's basis is fuzzed too
    return encode(header(skip_static=True, basis=basis), walk(30, 13), fpp)


@settings(max_examples=1000, deadline=None)
@given(st.binary(max_size=64), st.integers(0, 10_000), st.integers(0, 8), st.integers(1, 4))
def test_fuzz_nothing_but_our_errors_escape(junk, position, flips, fpp):
    """Junk and flipped bits anywhere, fed as a byte stream and as datagrams: only FdError escapes."""
    data = bytearray(frame_bytes(fuzz_packets(fpp)))
    position %= len(data)
    for i in range(flips):
        data[(position + 37 * i) % len(data)] ^= 1 << (i % 8)
    data[position:position] = junk
    for dec in (StreamDecoder(), DatagramDecoder()):
        try:
            if isinstance(dec, StreamDecoder):
                events = dec.feed(bytes(data[:position])) + dec.feed(bytes(data[position:])) + dec.close()
            else:
                ends = np.cumsum([len(p) for p in fuzz_packets(fpp)])  # the packets, damaged, as datagrams
                events = [e for a, b in zip([0, *ends[:-1]], ends) for e in dec.receive(bytes(data[a:b]))]
        except FdError:
            continue
        seqs = [f.seq for f in frames(events)]
        assert seqs == sorted(set(seqs))


@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(max_size=40), max_size=20))
def test_fuzz_datagrams(datagrams):
    packets = fuzz_packets(2)
    dec = DatagramDecoder()
    dec.receive(packets[0])
    for d in datagrams + packets[1:]:
        dec.receive(d)
    assert dec.ended


def test_delta_from_another_position_is_rejected():
    """On a byte stream it is damage; a datagram that cannot be read is dropped and counted, since on a
    socket it may not be ours (a lost packet of ours shows at the next keyframe)."""
    packets = encode(header(), walk(3, 13))  # header, keyframe 0, deltas 1 and 2, end
    events, _ = decode(frame_bytes(packets[:2] + [packets[3]]))
    assert isinstance(events[2], Damage)
    dec = DatagramDecoder()
    for p in packets[:2] + [packets[3]]:
        out = dec.receive(p)
    assert out == [] and dec.stats.skipped_bytes == len(packets[3]) and not dec.stats.damaged


def test_bitrate_choice_is_the_finest_level_that_codes_the_sample_within_the_target():
    from facedeform.protocol.rate import quality_for_bitrate, sample_bits_per_second

    sample = [(p, True) for p in walk(25, len(PAPER_PARAMS), seed=3)]  # a second of lively talking
    rates = {q: sample_bits_per_second(header(quality=q), sample, 2, 1.0) for q in QUALITIES}
    assert all(rates[q] < rates[q + 1] for q in QUALITIES[:-1])  # finer levels cost more
    for q in QUALITIES:
        assert quality_for_bitrate(lambda level: header(quality=level), sample, rates[q], 2, 1.0) == q
        below = quality_for_bitrate(lambda level: header(quality=level), sample, rates[q] * 0.999, 2, 1.0)
        assert below == max(q - 1, 1)
    # a model carried in-band is one-off: it does not count against the rate
    assert sample_bits_per_second(header(model_size=5000), sample, 2, 1.0) == rates[3]


@pytest.mark.parametrize("sealed, divisor", [(False, 1), (True, 1), (False, 2), (True, 3)])
def test_bitrate_estimate_is_what_the_stream_takes(sealed, divisor):
    """The estimate behind --bitrate counts every byte the call's stream carries per second: with
    --key the counter, tag and sync byte of each packet, with --send-every only the frames sent."""
    from facedeform.protocol.rate import sample_bits_per_second
    from facedeform.protocol.secure import SecureSealer

    h = header(divisor=divisor, key_interval=25 // divisor, skip_static=True)
    sample = [(p, True) for p in walk(25, len(PAPER_PARAMS), seed=4)]
    sealer = SecureSealer(bytes(32)) if sealed else None
    estimate = sample_bits_per_second(h, sample, 2, 1.0, sealer.overhead if sealed else 0)
    encoder = PacketEncoder(h, 2, dead_zone=1.0)
    packets = [p for params, seen in sample for p in encoder.frame(params, seen)] + encoder.end()[:-1]
    if sealed:
        packets = sealer.seal_all(packets)
    assert estimate == 8 * len(frame_bytes(packets, sealed))  # a second of frames: bits are bit/s


def test_over_datagrams_the_bitrate_estimate_counts_the_copies_they_carry():
    """Over UDP each datagram carries the packet before it again: --bitrate counts those bytes, which
    nearly double the frames' (the header's repeats for late joiners are not counted)."""
    from facedeform.protocol.encoder import COPIES, Datagrams
    from facedeform.protocol.rate import sample_bits_per_second

    h = header(skip_static=True)
    sample = [(p, True) for p in walk(25, len(PAPER_PARAMS), seed=5)]
    encoder = PacketEncoder(h, 2, dead_zone=1.0)
    packets = [p for params, seen in sample for p in encoder.frame(params, seen)] + encoder.end()[:-1]
    sent = Datagrams(b"", COPIES, header_every=0, eager=0).add(packets)
    plain = sample_bits_per_second(h, sample, 2, 1.0)
    assert sample_bits_per_second(h, sample, 2, 1.0, copies=COPIES) == 8 * sum(map(len, sent)) > 1.5 * plain


@pytest.mark.parametrize("width, height, rule", [(0, 0, "refined"), (640, 480, "paper"), (MAX_SIDE, 1, "paper")])
def test_frame_size_and_rule_travel_in_the_header(width, height, rule):
    h = header(width=width, height=height, rule=rule)
    back = parse_header(encode_header(h))
    assert back == h and (back.width, back.height, back.rule) == (width, height, rule)
    assert header(rule="paper") != header()


def test_how_long_a_picture_waits_for_the_next_video_frame_travels_in_the_header():
    """``ahead`` (frames) costs a byte where it is set and none where not; a byte of 0 or past MAX_AHEAD
    behind its flag is refused."""
    h = header(ahead=12)
    body, plain = encode_header(h), encode_header(header())
    assert parse_header(body).ahead == 12 and len(body) == len(plain) + 1
    at = next(i for i in range(4, len(plain)) if body[i] != plain[i])  # past the flags, the byte added
    assert body[at] == 12 and body[:3] + body[4:at] + body[at + 1:] == plain[:3] + plain[4:]
    for value, message in ((0, "wait 0 frames"), (MAX_AHEAD + 1, f"wait {MAX_AHEAD + 1} frames")):
        with pytest.raises(BitstreamError, match=message):
            StreamDecoder().feed(header_bytes_with(h, at, bytes([value])))
    with pytest.raises(ValueError, match="out of range"):
        header(ahead=MAX_AHEAD + 1)


@pytest.mark.parametrize("change", [{"width": MAX_SIDE + 1}, {"height": -1}, {"rule": "other"},
                                    {"steps": steps_for(PAPER_PARAMS) * 1e306}, {"steps": -steps_for(PAPER_PARAMS)}])
def test_header_fields_out_of_range_are_a_callers_mistake(change):
    with pytest.raises(ValueError):
        replace(header(), **change)


def test_a_quality_levels_steps_are_named_not_written():
    """Steps that are exactly a quality level's cost no bytes (the level byte says them); any other
    steps are written out, and both come back exactly."""
    for h in (header(), header(quality=5), CUSTOM):
        back = parse_header(encode_header(h))
        assert back == h and np.array_equal(back.steps, h.steps)
    assert len(encode_header(CUSTOM)) - len(encode_header(header())) == 8 * len(PAPER_PARAMS)


def header_bytes_with(h: Header, at: int, value: bytes, length: int = 1) -> bytes:
    body = bytearray(encode_header(h))
    body[at:at + length] = value
    return build(HEADER, bytes(body))


@pytest.mark.parametrize("patch, message", [
    (lambda h: header_bytes_with(h, 7, b"\x02"), "unknown deformation rule 2"),
    (lambda h: header_bytes_with(h, 3, b"\x80"), "unknown header flags"),
    (lambda h: header_bytes_with(h, 3, b"\x14"), "unknown header flags"),  # a held layout's basis written too
    (lambda h: header_bytes_with(header(NAMED["mouth"]), 3, b"\x10"),  # its count of 39 names read as an index
     "layout 39, which this decoder does not hold"),
    (lambda h: header_bytes_with(h, 8 + len(varint(25000)), b"\x81\x80\x01"), "over its limit"),  # width 16385
    (lambda h: header_bytes_with(CUSTOM, len(encode_header(CUSTOM)) - 8, np.float64(1e306).byteswap().tobytes(), 8),
     "quantiser steps"),
    (lambda h: header_bytes_with(CUSTOM, len(encode_header(CUSTOM)) - 8, np.float64(np.nan).byteswap().tobytes(), 8),
     "quantiser steps"),
    (lambda h: header_bytes_with(h, 4, b"\x00"), "quality level 0, which is none"),  # level steps of no level
])
def test_hostile_header_values_are_refused_at_parse(patch, message):
    """A step that could make a decoded value non-finite (1e306 times an index) is refused with the
    header, not met as a traceback later."""
    with pytest.raises(BitstreamError, match=message):
        StreamDecoder().feed(patch(header()))


def keyframe_at(h: Header, coded: int) -> list[bytes]:
    """The packets of a keyframe numbered ``coded`` (a multiple of the key interval), as the project's
    encoder makes them: the encoder as if it had coded that many frames already."""
    enc = PacketEncoder(h)
    enc._frames = coded * h.divisor
    return enc.frame(np.zeros(len(h.names)), True)


def end_mark(frames: int) -> bytes:
    return build(END, varint(frames))


def hostile_streams() -> dict[str, list[bytes]]:
    """Streams whose every packet passes its check, each claiming frames no received bytes paid for."""
    h, slow = header(), header(divisor=16, key_interval=250)
    packets = encode(h, walk(10, 13))
    return {
        "end mark of 2**40 - 1 frames": packets[:1] + [end_mark(2**40 - 1)],
        "end mark of 10**6 frames after 10": packets[:-1] + [end_mark(10**6)],
        "keyframe 10**9": packets[:1] + keyframe_at(h, 10**9) + [end_mark(10**9 * 1 + 1)],
        "sequence jump to 4e9": packets[:-1] + keyframe_at(h, 4 * 10**9) + packets[1:3],
        "divisor 16, keyframe 10**6": encode(slow, walk(20, 13))[:-1] + keyframe_at(slow, 10**6),
        "divisor 16, end mark": encode(slow, walk(20, 13))[:-1] + [end_mark(16 * 10**7)],
    }


@pytest.mark.parametrize("name", sorted(hostile_streams()))
@pytest.mark.parametrize("transport", ["stream", "datagrams"])
def test_hostile_claims_are_damage_in_bounded_memory(name, transport):
    """Each claim is a Damage event and the decoder waits for the next keyframe; memory stays small."""
    import tracemalloc

    packets = hostile_streams()[name]
    tracemalloc.start()
    try:
        if transport == "stream":
            dec = StreamDecoder()
            events = dec.feed(frame_bytes(packets)) + dec.close()
        else:
            dec = DatagramDecoder()
            events = [e for p in packets for e in dec.receive(p)]
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 2 << 20, f"{peak} bytes"
    if name == "keyframe 10**9" and transport == "datagrams":  # a receiver joining late starts there
        assert [f.seq for f in frames(events)] == [10**9] and events[-1] == End(1)
        return
    damage = [e for e in events if isinstance(e, Damage)]
    assert damage and any("ahead" in e.reason or "end mark claims" in e.reason for e in damage)
    assert len(frames(events)) <= 16 * 30 and not any(isinstance(e, End) and e.frames > 100 for e in events)


def test_a_keyframe_far_ahead_is_taken_once_enough_bytes_arrived():
    """The bound is on frames per received byte, not on gaps: after a long outage (datagrams lost)
    the first keyframe is refused, and the packets that follow pay for the gap."""
    packets = encode(header(key_interval=25), walk(2000, 13), fpp=2)
    keys = [i for i, p in enumerate(packets) if p[:1] == bytes([SYNC]) and p[1] >> 5 == 2]
    first = keys[60]  # frame 1500: 1475 frames after the last one received, more than its bytes allow
    dec = DatagramDecoder()
    events = [e for p in packets[:keys[1]] + packets[first:] for e in dec.receive(p)]
    got = frames(events)
    assert [f.seq for f in got] == list(range(2000)) and dec.ended
    assert [f.seq for f in got if f.concealed] == list(range(25, 1525))
    assert [e.seq for e in events if isinstance(e, Damage) and "ahead" in e.reason] == [25]


def test_damage_before_the_first_keyframe_is_reported():
    """A byte stream starts at its beginning: its first keyframe damaged is damage to report (it was
    concealed in silence, as if the receiver had joined late), once until the next keyframe."""
    h = header(key_interval=10)
    packets = encode(h, walk(30, 13), fpp=2)
    data = bytearray(frame_bytes(packets))
    first_key = len(frame_bytes(packets[:1]))  # the header packet, then the first keyframe
    data[first_key + 4] ^= 0xFF
    events, dec = decode(bytes(data))
    damage = [e for e in events if isinstance(e, Damage)]
    assert len(damage) == 1 and damage[0].seq == 0 and dec.stats.damaged == 1
    assert len(frames(events)) == 30  # concealed until the keyframe at frame 10, then decoded
