"""Sealed streams (protocol/secure.py): round trips, tampering, replays, wrong keys. No I/O."""

import os

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from facedeform.common.errors import BitstreamError, FdError, InputError
from facedeform.common.keys import key_id, parse_key
from facedeform.common.parameters import PAPER_PARAMS, POSE_PARAMS, UPPER_PARAMS
from facedeform.protocol.decoder import PacketDecoder
from facedeform.protocol.framing import varint
from facedeform.protocol.secure import SecureOpener, SecureSealer, preamble_size
from facedeform.protocol.secure_stream import SecureDatagramDecoder, SecureStreamDecoder, seal_stream
from facedeform.protocol.stream import DatagramDecoder, Frame, Header, Model, PacketEncoder, frame_bytes, steps_for

KEY = bytes(range(32))
LAYOUTS = {"paper": PAPER_PARAMS + POSE_PARAMS[:3], "full": PAPER_PARAMS + UPPER_PARAMS + POSE_PARAMS}
MODEL = bytes(range(256)) * 9  # three model chunks, contents opaque to the protocol


def clear_packets(names, fpp=2, n=60, model=b"") -> list[bytes]:
    header = Header(25.0, names, steps_for(names), "ab" * 32, key_interval=25, model_size=len(model))
    enc = PacketEncoder(header, fpp, model)
    t = np.arange(n)[:, None] / 25.0
    params = 0.01 * np.sin(2 * np.pi * 1.3 * t + np.arange(len(names)))
    packets = enc.header()
    for p in params:
        packets += enc.frame(p, True)
    return packets + enc.end()


def events_of(decoder, packets) -> list:
    return [e for p in packets for e in decoder.receive(p)]


def frames(events) -> list[tuple[int, bytes, bool]]:
    return [(e.seq, e.params.tobytes(), e.concealed) for e in events if isinstance(e, Frame)]


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
@pytest.mark.parametrize("fpp", [1, 2, 5])
@pytest.mark.parametrize("tag_bits", [32, 64, 128])
def test_round_trip_on_every_layout_datagrams_and_bytes(layout, fpp, tag_bits):
    packets = clear_packets(LAYOUTS[layout], fpp, model=MODEL)
    sealed = seal_stream(SecureSealer(KEY, tag_bits), packets)
    assert [len(s) for s in sealed[1:]] == [len(p) + 2 + len(varint(len(p))) + tag_bits // 8 for p in packets]
    assert not any(p in s for p, s in zip(packets, sealed[1:]))  # nothing in clear
    expected = events_of(DatagramDecoder(), packets)
    dec = SecureDatagramDecoder(KEY)
    got = events_of(dec, sealed)
    assert frames(got) == frames(expected) and len(frames(got)) == 60
    assert [e.data for e in got if isinstance(e, Model)] == [MODEL] and dec.ended
    stream = SecureStreamDecoder(KEY)
    data = frame_bytes(sealed, sealed=True)
    got = [e for i in range(0, len(data), 5) for e in stream.feed(data[i:i + 5])] + stream.close()
    assert frames(got) == frames(expected) and stream.security.opened == len(packets)


def test_a_flipped_bit_anywhere_is_rejected_and_changes_nothing():
    packets = clear_packets(LAYOUTS["paper"], 2, n=30)
    sealed = seal_stream(SecureSealer(KEY), packets)
    dec = SecureDatagramDecoder(KEY)
    dec.receive(sealed[0])
    flips = 0
    for s in sealed[1:]:
        for bit in range(8 * len(s)):
            bad = bytearray(s)
            bad[bit // 8] ^= 1 << bit % 8
            assert dec.receive(bytes(bad)) == []
            flips += 1
        assert dec.receive(s) is not None
    # a flipped counter bit may name a packet already seen: then it is dropped as a replay
    assert dec.security.auth_failures + dec.security.replays == flips and dec.security.opened == len(packets)
    assert dec.stats.damaged == 0 and dec.ended


def test_a_flipped_bit_in_a_byte_stream_never_renders_a_wrong_frame():
    packets = clear_packets(LAYOUTS["paper"], 2, n=50)
    data = frame_bytes(seal_stream(SecureSealer(KEY), packets), sealed=True)
    truth = {seq: params for seq, params, _ in frames(events_of(DatagramDecoder(), packets))}
    start = preamble_size(4) + 1
    for bit in range(8 * start, 8 * len(data), 37):
        bad = bytearray(data)
        bad[bit // 8] ^= 1 << bit % 8
        dec = SecureStreamDecoder(KEY)
        try:
            got = frames(dec.feed(bytes(bad)) + dec.close())
        except BitstreamError:  # the header packet was hit: no stream, nothing rendered
            continue
        assert all(params == truth[seq] for seq, params, concealed in got if not concealed)
        assert dec.security.auth_failures + dec.stats.skipped_bytes > 0


def test_replays_and_packets_older_than_the_window_are_rejected():
    sealed = seal_stream(SecureSealer(KEY), [bytes([i]) * 3 for i in range(200)])
    opener = SecureOpener(KEY, window=64)
    assert opener.preamble(sealed[0])
    assert opener.open(sealed[1]) == b"\0" * 3
    assert opener.open(sealed[1]) is None  # replay
    for s in sealed[3:100]:
        assert opener.open(s) is not None
    assert opener.open(sealed[60]) is None  # seen
    assert opener.open(sealed[2]) is None  # never seen, but 97 packets late: beyond the window
    assert opener.open(sealed[40]) is None  # ... 59 late, yet seen
    assert opener.stats.replays == 4 and opener.stats.opened == 98


def test_reordering_inside_the_window_is_accepted():
    sealed = seal_stream(SecureSealer(KEY), [bytes([i]) for i in range(10)])
    opener = SecureOpener(KEY)
    opener.preamble(sealed[0])
    order = [1, 3, 2, 5, 4, 10, 6, 9, 7, 8]
    assert [opener.open(sealed[i]) for i in order] == [bytes([i - 1]) for i in order]


def test_the_counter_rolls_over_across_long_gaps():
    sealer = SecureSealer(KEY)
    opener = SecureOpener(KEY)
    opener.preamble(sealer.preamble())
    sealed = [sealer.seal(i.to_bytes(3, "big")) for i in range(70_001)]
    for i in range(0, 70_001, 10_000):  # gaps under 2**15 packets keep sync through a rollover
        assert opener.open(sealed[i]) == i.to_bytes(3, "big")


def test_a_wrong_key_gives_no_frame_and_says_so():
    sealed = seal_stream(SecureSealer(KEY), clear_packets(LAYOUTS["paper"]))
    other = os.urandom(32)
    dec = SecureDatagramDecoder(other)
    assert events_of(dec, sealed) == [] and dec.header is None
    assert key_id(KEY).hex() in dec.no_stream() and "another key" in dec.no_stream()
    stream = SecureStreamDecoder(other)
    assert stream.feed(frame_bytes(sealed, sealed=True)) == []
    with pytest.raises(BitstreamError, match="another key"):
        stream.close()


def test_a_forged_preamble_or_clear_stream_opens_nothing():
    preamble = bytearray(SecureSealer(KEY).preamble())
    preamble[10] ^= 1  # the salt: keys change, its tag fails
    opener = SecureOpener(KEY)
    assert not opener.preamble(bytes(preamble)) and not opener.ready and opener.stats.auth_failures == 1
    stream = SecureStreamDecoder(KEY)
    stream.feed(frame_bytes(clear_packets(LAYOUTS["paper"])))
    with pytest.raises(BitstreamError, match="--key"):
        stream.close()


def test_junk_datagrams_leave_the_real_stream_untouched():
    rng = np.random.default_rng(1)
    packets = clear_packets(LAYOUTS["paper"], 2, n=100)
    sealed = seal_stream(SecureSealer(KEY), packets)
    dec = SecureDatagramDecoder(KEY)
    got = []
    for i, s in enumerate(sealed):
        got += dec.receive(s)
        junk = [rng.bytes(int(rng.integers(0, 300))) for _ in range(20)] + sealed[max(0, i - 3):i]
        for j in junk:
            got += dec.receive(j)
    assert frames(got) == frames(events_of(DatagramDecoder(), packets))
    assert dec.stats.damaged == 0 and dec.security.opened == len(packets)


@pytest.mark.parametrize("text", ["", "zz" * 32, "ab" * 31, "ab" * 32 + "\n" + "cd" * 32])
def test_malformed_keys_are_refused(text):
    with pytest.raises(InputError, match="fd-keygen"):
        parse_key(text)
    assert parse_key("# comment\n" + "ab" * 32 + "\n") == bytes([0xAB]) * 32


def test_tag_lengths_outside_the_range_are_refused():
    for bits in (0, 24, 36, 136):
        with pytest.raises(InputError):
            SecureSealer(KEY, bits)


def test_an_old_preamble_replayed_first_cannot_lock_the_receiver_out():
    old = seal_stream(SecureSealer(KEY), clear_packets(LAYOUTS["paper"], n=10))
    packets = clear_packets(LAYOUTS["paper"], n=10)
    new = seal_stream(SecureSealer(KEY), packets)
    dec = SecureDatagramDecoder(KEY)
    got = events_of(dec, [old[0]] + new)
    assert frames(got) == frames(events_of(DatagramDecoder(), packets)) and dec.ended
    stream = SecureStreamDecoder(KEY)
    got = stream.feed(frame_bytes([old[0]] + new, sealed=True)) + stream.close()
    assert frames(got) == frames(events_of(DatagramDecoder(), packets))


def test_every_flipped_bit_is_refused_before_the_decoder_sees_the_packet(monkeypatch):
    """Byte stream: whichever bit flips, the packet holding it never reaches the packet decoder
    (its envelope's tag is checked first), and every other packet does, unchanged."""
    packets = clear_packets(LAYOUTS["paper"], 2, n=12)
    sealed = seal_stream(SecureSealer(KEY), packets)
    data = frame_bytes(sealed, sealed=True)
    starts = np.cumsum([0] + [1 + len(s) for s in sealed])  # each sealed packet's sync byte
    seen: list[bytes] = []
    inner = PacketDecoder.packet
    monkeypatch.setattr(PacketDecoder, "packet",
                        lambda self, data, at: seen.append(bytes(data)) or inner(self, data, at))
    for bit in range(8 * starts[1], 8 * len(data)):
        bad = bytearray(data)
        bad[bit // 8] ^= 1 << bit % 8
        hit = int(np.searchsorted(starts, bit // 8, side="right")) - 2  # index in packets
        seen.clear()
        dec = SecureStreamDecoder(KEY)
        try:
            dec.feed(bytes(bad))
            dec.close()
        except BitstreamError:
            assert hit == 0  # the header's packet: no stream
        assert seen == packets[:hit] + packets[hit + 1:], bit
        assert dec.security.auth_failures + dec.stats.skipped_bytes >= 1


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=64), st.integers(0, 10_000), st.integers(0, 8), st.booleans())
def test_fuzz_sealed_streams_raise_nothing_but_our_errors(junk, position, flips, inside):
    """Junk and flipped bits in a sealed byte stream, or in the packets before sealing (what a key
    holder could send): nothing but FdError escapes, and frames stay in order."""
    packets = clear_packets(LAYOUTS["paper"], 2, n=20)
    if inside:  # authentic garbage: the packet decoder's own defences
        clear = bytearray(b"".join(packets[1:]))
        position %= len(clear)
        for i in range(flips):
            clear[(position + 37 * i) % len(clear)] ^= 1 << (i % 8)
        cuts = sorted({0, len(clear), *(position + 11 * i for i in range(len(junk)) if position + 11 * i < len(clear))})
        packets = packets[:1] + [bytes(clear[a:b]) for a, b in zip(cuts, cuts[1:])]
    data = bytearray(frame_bytes(seal_stream(SecureSealer(KEY), packets), sealed=True))
    if not inside:
        position %= len(data)
        for i in range(flips):
            data[(position + 37 * i) % len(data)] ^= 1 << (i % 8)
        data[position:position] = junk
    for dec in (SecureStreamDecoder(KEY), SecureDatagramDecoder(KEY)):
        try:
            if isinstance(dec, SecureStreamDecoder):
                events = dec.feed(bytes(data[:position])) + dec.feed(bytes(data[position:])) + dec.close()
            else:
                events = [e for chunk in (data[:position], junk, data[position:]) for e in dec.receive(bytes(chunk))]
        except FdError:
            continue
        seqs = [e.seq for e in events if isinstance(e, Frame)]
        assert seqs == sorted(set(seqs))
