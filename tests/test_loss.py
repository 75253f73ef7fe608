"""Lossy links and late join: datagrams that carry the packets before them again, headers sent again at
keyframes, over a deterministic in-memory link and over loopback UDP."""

import socket
import threading
import time
from dataclasses import replace

import numpy as np
import pytest

from facedeform.common.errors import InputError
from facedeform.protocol.encoder import COPIES, HEADER_EVERY
from facedeform.protocol.secure import SecureSealer
from facedeform.protocol.secure_stream import SecureDatagramDecoder
from facedeform.protocol.stream import DatagramDecoder, Datagrams, Frame, Header, PacketEncoder
from facedeform.sender.config import DATAGRAM_FRAMES
from facedeform.sender.session import DATAGRAM_KEYS
from facedeform.sender.transport import open_sink
from tests.support import FPS, KEY, N, finish, header, parse_y4m, smooth_tracks, start_listener, stream_datagrams

RNG_SEEDS = range(5)


def receive(dec, stream: list[bytes]) -> list[Frame]:
    return [e for d in stream for e in dec.receive(d) if isinstance(e, Frame)]


def random_loss(stream: list[bytes], rate: float, seed: int, keep: int = 1) -> list[bytes]:
    """``stream`` with each datagram after the first ``keep`` and before the last two (the end mark,
    sent twice) lost at ``rate``."""
    lost = np.random.default_rng(seed).random(len(stream)) < rate
    lost[:keep] = lost[-2:] = False
    return [d for d, gone in zip(stream, lost) if not gone]


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_five_percent_random_loss_keeps_95_percent_of_frames_good_and_delivers_every_one(seed):
    """A minute of call: a datagram lost alone costs nothing; two in a row (a quarter of a percent)
    cost the frames up to the next keyframe."""
    n = 1500
    stream, sent = stream_datagrams(smooth_tracks(n))
    got = receive(DatagramDecoder(), random_loss(stream, 0.05, seed))
    assert [f.seq for f in got] == list(range(n))
    good = [f for f in got if not f.concealed]
    assert len(good) >= 0.95 * n
    np.testing.assert_allclose([f.params for f in good], [sent[f.seq] for f in good], atol=1e-9)


def test_one_lost_datagram_costs_no_frame_and_without_copies_only_a_concealed_second():
    """Each frames datagram lost alone, in turn: with one copy nothing is concealed; without, the
    frames up to the next keyframe are, interpolated between the last good frame and it."""
    params = smooth_tracks()
    for copies in (1, 0):
        stream, sent = stream_datagrams(params, copies)
        for lost in range(2, len(stream) - 2):
            got = receive(DatagramDecoder(), stream[:lost] + stream[lost + 1:])
            assert [f.seq for f in got] == list(range(N))
            concealed = [f.seq for f in got if f.concealed]
            if copies:
                assert not concealed, lost
                continue
            assert concealed and len(concealed) <= KEY and concealed[-1] + 1 == min(N, (concealed[0] // KEY + 1) * KEY)
            if concealed[-1] + 1 < N:  # between two good frames: a straight line from one to the other
                a, b = concealed[0] - 1, concealed[-1] + 1
                for f in got[concealed[0]:b]:
                    t = (f.seq - a) / (b - a)
                    np.testing.assert_allclose(f.params, sent[a] + t * (sent[b] - sent[a]), atol=1e-9)


def longest_freeze(frames: list[Frame], n: int) -> int:
    good = np.zeros(n, bool)
    for f in frames:
        good[f.seq] = not f.concealed
    runs = longest = 0
    for g in good:
        runs = 0 if g else runs + 1
        longest = max(longest, runs)
    return longest


@pytest.mark.parametrize("at", [20, 33, 47, 61])
def test_a_burst_of_three_freezes_the_face_at_most_twelve_frames_over_datagrams(at):
    """One copy of each packet does not survive three datagrams lost in a row: the face is concealed
    until the next keyframe. fd-send's keyframe a second froze it for up to a second and a half; over
    datagrams it sends one every 0.24 s (sender.session.DATAGRAM_KEYS)."""
    params = smooth_tracks()
    keys = round(DATAGRAM_KEYS * 25)
    froze = {}
    for interval in (25, keys):
        enc = PacketEncoder(replace(header(), key_interval=interval), 2)
        head = enc.header()
        pack = Datagrams(head[0], 1)
        stream = pack.add(head)
        for x in params:
            stream += pack.add(enc.frame(x, True))
        stream += pack.add(enc.end())
        kept = stream[:at] + stream[at + 3:]
        froze[interval] = longest_freeze(receive(DatagramDecoder(), kept), len(params))
    assert froze[25] > 12 and 0 < froze[keys] <= 12  # a keyframe a second froze longer


def burst_freezes(per_packet: int, key_interval: int, burst: int, n: int = 75) -> list[int]:
    """The longest concealed run in ``n`` frames when ``burst`` datagrams in a row are lost, for each
    place the burst can start, with fd-send's copies."""
    enc = PacketEncoder(replace(header(), key_interval=key_interval), per_packet)
    head = enc.header()
    pack = Datagrams(head[0], COPIES)
    stream = pack.add(head)
    for x in smooth_tracks(n):
        stream += pack.add(enc.frame(x, True))
    stream += pack.add(enc.end())
    return [longest_freeze(receive(DatagramDecoder(), stream[:at] + stream[at + burst:]), n)
            for at in range(1, len(stream) - 2 - burst)]


def test_a_burst_of_eight_datagrams_is_concealed_at_most_twelve_frames_with_fd_sends_datagrams():
    """Eight datagrams lost in a row, wherever they fall: at fd-send's frame a datagram and keyframe
    every 0.24 s the face is concealed for at most 12 frames; at 2 frames a datagram and a keyframe
    every 0.4 s (fd-send before) the same bursts froze it longer (16 frames here, 18 on four dev clips'
    streams)."""
    new = burst_freezes(DATAGRAM_FRAMES, round(DATAGRAM_KEYS * FPS), 8)
    old = burst_freezes(2, 10, 8)
    assert 0 < max(new) <= 12 < max(old)


@pytest.mark.parametrize("at", [20, 33, 47, 61])
def test_with_fd_sends_copies_a_burst_of_three_costs_no_frame(at):
    """The burst that froze the face with one copy: with COPIES (three) the datagram after it carries
    the three lost packets again, and every frame is drawn exactly as the sender coded it."""
    params = smooth_tracks()
    stream, sent = stream_datagrams(params, COPIES)
    got = receive(DatagramDecoder(), stream[:at] + stream[at + 3:])
    assert [f.seq for f in got] == list(range(len(params))) and not any(f.concealed for f in got)
    np.testing.assert_allclose([f.params for f in got], sent, atol=1e-9)


def test_copies_and_sealing_survive_loss_together():
    sealer = SecureSealer(b"k" * 32)
    stream, _ = stream_datagrams(smooth_tracks(), sealer=sealer)
    dec = SecureDatagramDecoder(b"k" * 32)
    got = receive(dec, random_loss(stream, 0.05, 1, keep=2))
    assert [f.seq for f in got] == list(range(N)) and sum(f.concealed for f in got) <= 0.05 * N
    assert dec.security.auth_failures == dec.security.replays == 0


def test_copies_cost_about_one_packet_more_per_datagram():
    """What the redundancy costs, as docs/bitstream.md reports it: each delta's datagram carries one
    packet more, so the frames' bytes about double; the header and end are sent as they are."""
    plain, _ = stream_datagrams(smooth_tracks(), copies=0)
    copied, _ = stream_datagrams(smooth_tracks(), copies=1)
    ratio = sum(map(len, copied[1:])) / sum(map(len, plain[1:]))
    assert 1.6 < ratio < 2.1


def test_a_receiver_joining_late_renders_from_the_keyframe_after_the_header():
    stream, sent = stream_datagrams(smooth_tracks(), header_every=1)
    start = len(stream) // 3  # mid-call: the first header and keyframes are gone
    got = receive(DatagramDecoder(), stream[start:])
    first = got[0].seq
    assert first % KEY == 0 and 0 < first < N and [f.seq for f in got] == list(range(first, N))
    assert not any(f.concealed for f in got)
    np.testing.assert_allclose([f.params for f in got], sent[first:], atol=1e-9)


def test_a_receiver_joining_late_reports_no_loss_wherever_it_joins():
    """Its first keyframe may come as a copy in a later datagram (the keyframe's own came before it
    joined): not a repair, or its first report would tell the sender the link loses (sender/link.py:
    20 s at the full cost)."""
    stream, _ = stream_datagrams(smooth_tracks(), COPIES, eager=0, header_every=0)
    for start in range(len(stream) // 3, len(stream) // 3 + KEY // 2):  # a key's datagrams and more
        dec = DatagramDecoder([header()])
        got = receive(dec, stream[start:])
        assert got[-1].seq == N - 1 and dec.stats.repaired == dec.stats.concealed == 0, start


def test_a_sealed_stream_can_be_joined_late_too():
    """The preamble goes again with the header; copies of it are ignored once one is taken."""
    stream, sent = stream_datagrams(smooth_tracks(), header_every=1, sealer=SecureSealer(b"k" * 32))
    dec = SecureDatagramDecoder(b"k" * 32)
    got = receive(dec, stream[len(stream) // 3:])
    first = got[0].seq
    assert first % KEY == 0 and [f.seq for f in got] == list(range(first, N)) and dec.ended
    np.testing.assert_allclose([f.params for f in got], sent[first:], atol=1e-9)
    assert dec.security.auth_failures == dec.security.replays == 0


def test_a_receiver_holding_the_header_starts_at_the_first_keyframe_and_ignores_others():
    """No header is sent again: the keyframes name it, and the receiver holds it already."""
    stream, _ = stream_datagrams(smooth_tracks(), eager=0, header_every=0)
    start = len(stream) // 3
    other = Header(25.0, header().names, header().steps * 2, header().face_id, key_interval=KEY)
    assert not receive(DatagramDecoder([other]), stream[start:])
    dec = DatagramDecoder([other, header()])
    got = receive(dec, stream[start:])
    assert dec.header == header() and got[0].seq % KEY == 0 and [f.seq for f in got] == list(range(got[0].seq, N))


def test_the_header_goes_again_before_the_first_keyframes_then_every_nth():
    enc = PacketEncoder(header(), 2)
    head = enc.header()
    pack = Datagrams(head[0], copies=0, header_every=5, eager=2)
    out = pack.add(head)
    for x in smooth_tracks(KEY * 12):
        out += pack.add(enc.frame(x, True))
    keys = [i for i, d in enumerate(out) if header().ident in d]  # keyframe packets name their header
    assert len(keys) == 12
    assert [i for i, d in enumerate(out) if d == head[0]] == [0] + [keys[n] - 1 for n in (1, 2, 5, 10)]


def test_keyframes_at_some_key_places_decode_the_same_and_keep_the_headers_pace():
    """An encoder told to key only every 2nd key place (fd-send while the link is clean,
    sender/link.LEAN_KEYS) from the third place on: the decoder takes its deltas at the places it
    skipped and outputs the same values as a stream keyed at every place; the header's repeats,
    counted by key place, keep their place in time, and stop before the eager keyframes once the
    receiver has joined."""
    tracks = smooth_tracks(KEY * 12)
    streams = {}
    for every in (1, 2):
        enc = PacketEncoder(header(), 2)
        head = enc.header()
        pack = Datagrams(head[0], copies=0, header_every=3, eager=4, key_interval=KEY)
        out = pack.add(head)
        for i, x in enumerate(tracks):
            enc.key_every = every if i >= 2 * KEY else 1
            out += pack.add(enc.frame(x, True))
        streams[every] = out + pack.add(enc.end())
    keyed, lean = ([i for i, d in enumerate(s) if header().ident in d] for s in (streams[1], streams[2]))
    assert len(keyed) == 12 and len(lean) == 2 + 5  # places 0, 1, then 2, 4, 6, 8, 10
    got = [[f.params for f in receive(DatagramDecoder([header()]), streams[e])] for e in (1, 2)]
    assert len(got[0]) == len(got[1]) == KEY * 12 and np.array_equal(got[0], got[1])
    repeats = [i for i, d in enumerate(streams[2]) if d == streams[2][0]]
    # eager at places 1, 2, 4 (each keyframe up to the 4th place), then at 6 and 10 (past 6 and 9)
    assert repeats == [0] + [lean[n] - 1 for n in (1, 2, 3, 4, 6)]
    enc = PacketEncoder(header(), 2)
    pack = Datagrams(enc.header()[0], copies=0, header_every=0, eager=4, key_interval=KEY)
    pack.add(enc.header())
    pack.joined = True  # the receiver reported: it holds the header
    assert all(d != enc.header()[0] for x in tracks[:KEY * 4] for d in pack.add(enc.frame(x, True)))


def test_the_eager_repeats_are_counted_apart_from_the_later_ones():
    """What the sender's rate keeper leaves room for beside the frames (sender/session.py): the repeats
    the later pace would not have sent. Eager before each of the first 4 keyframe places, later every
    3rd: repeats at places 1, 2, 3, 4, 6 and 9, of which 1, 2 and 4 are eager."""
    enc = PacketEncoder(header(), 2)
    head = enc.header()[0]
    pack = Datagrams(head, copies=0, header_every=3, eager=4, key_interval=KEY)
    pack.add(enc.header())
    for x in smooth_tracks(KEY * 10):
        pack.add(enc.frame(x, True))
    assert pack.repeated == 6 * len(head) and pack.eager_repeated == 3 * len(head)


def test_a_small_header_goes_again_more_often_than_a_large_one():
    """By default the repeats cost at most 80 bits a keyframe (REPEAT_BITS): a header of 56 bytes (fd-send's
    default layout) every 6th keyframe, one of a kilobyte or more every HEADER_EVERY-th."""
    assert Datagrams(bytes(56)).repeat_rate(0.4) == 8 * 56 / (6 * 0.4)
    assert Datagrams(bytes(2000)).repeat_rate(0.4) == 8 * 2000 / (HEADER_EVERY * 0.4)
    assert Datagrams(bytes(5)).repeat_rate(1.0) == 8 * 5 / 1.0  # never more often than every keyframe
    assert Datagrams(bytes(233)).repeat_rate(1.0) == 8 * 233 / 24  # a speaker's own layout: 1864 / 80 bits


def test_while_the_receiver_reports_a_clean_link_the_header_goes_every_header_every_th_place():
    """A receiver that reports holds the header; one that restarts reports nothing until it has one
    (receiver/transport.py), so the lean spell ends and the repeats come as often as before."""
    enc = PacketEncoder(header(), 2)
    pack = Datagrams(enc.header()[0], copies=0, header_every=3, eager=0, key_interval=KEY)
    pack.add(enc.header())
    places = []
    for i, x in enumerate(smooth_tracks(KEY * (2 * HEADER_EVERY + 1))):
        pack.lean = i // KEY < 2 * HEADER_EVERY - 3
        places += [i // KEY] * sum(d == enc.header()[0] for d in pack.add(enc.frame(x, True)))
    assert places == [HEADER_EVERY, 2 * HEADER_EVERY - 3, 2 * HEADER_EVERY]  # lean, then every 3rd again


def test_the_header_does_not_go_again_with_the_streams_end():
    """The last keyframe, flushed with the end mark, goes without the header: a receiver joining then
    would draw a frame, and over a 2-second window at 4 kbit/s a speaker's own header was a fifth
    of the rate (benchmarks/bench_picture_layer.py --udp)."""
    enc = PacketEncoder(header(), 2)
    pack = Datagrams(enc.header()[0], copies=0, header_every=1, eager=0)
    pack.add(enc.header())
    before = [pack.add(enc.frame(x, True)) for x in smooth_tracks(KEY * 3 + 1)]  # the last a keyframe, pending
    keyed = [d for d in before[:-1] if any(header().ident in p for p in d)]
    assert len(keyed) == 3 and all(enc.header()[0] in d for d in keyed[1:])  # (none before the first)
    end = pack.add(enc.end())
    assert any(header().ident in d for d in end) and enc.header()[0] not in end


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_over_udp_five_percent_loss_keeps_95_percent_good(tmp_path):
    stream, _ = stream_datagrams(smooth_tracks())
    proc, port = start_listener("udp://127.0.0.1:0", tmp_path)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for d in random_loss(stream, 0.05, 11):
            sock.sendto(d, ("127.0.0.1", port))
            time.sleep(0.002)  # a sender's pace: a burst could overflow the receiver's socket, which is not the loss
    stats, _ = finish(proc)
    dump = np.load(tmp_path / "recv.npz")
    np.testing.assert_array_equal(dump["seq"], np.arange(N))
    assert stats["frames"] == N and stats["concealed"] <= 0.05 * N and stats["ended"]


@pytest.mark.slow
def test_a_receiver_started_after_the_sender_renders_from_the_next_keyframe(tmp_path):
    """The sender is already sending at the stream's rate when fd-recv starts listening."""
    stream, _ = stream_datagrams(smooth_tracks(), header_every=1)
    port = free_udp_port()
    sent_into_nothing, listening = threading.Event(), threading.Event()

    def send():
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            for i, d in enumerate(stream):
                if i == len(stream) // 3:
                    sent_into_nothing.set()
                    listening.wait(60)
                sock.sendto(d, ("127.0.0.1", port))
                time.sleep(2 / 25)  # a live sender's pace, so that the receiver's socket never overflows

    sender = threading.Thread(target=send)
    sender.start()
    assert sent_into_nothing.wait(60)  # the header and the first third went to nobody
    proc, _ = start_listener(f"udp://127.0.0.1:{port}", tmp_path)
    listening.set()
    stats, _ = finish(proc)
    sender.join()
    dump = np.load(tmp_path / "recv.npz")
    first = int(dump["seq"][0])
    assert first > 0 and first % KEY == 0
    np.testing.assert_array_equal(dump["seq"], np.arange(first, N))
    assert stats["concealed"] == 0 and stats["ended"] and parse_y4m((tmp_path / "out.y4m").read_bytes())[1] == N - first


def test_a_tcp_sender_waits_for_the_receiver(monkeypatch):
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:  # a free port, bound a moment later
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    got, refused = [], threading.Event()
    connect = socket.create_connection

    def connect_noting_refusals(*args, **kwargs):
        try:
            return connect(*args, **kwargs)
        except ConnectionRefusedError:
            refused.set()
            raise

    monkeypatch.setattr("facedeform.sender.transport.socket.create_connection", connect_noting_refusals)

    def listen_later():
        assert refused.wait(60)  # the sender has tried once while nobody listened
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as server:
            server.bind(("127.0.0.1", port))
            server.listen(1)
            conn, _ = server.accept()
            with conn:
                got.append(conn.recv(100))

    listener = threading.Thread(target=listen_later)
    listener.start()
    sink = open_sink(f"tcp://127.0.0.1:{port}")
    sink.write([b"\xfdhello"])
    sink.close()
    listener.join(30)
    assert got == [b"\xfdhello"]
    monkeypatch.setattr("facedeform.sender.transport.CONNECT_WAIT", 0.3)
    with pytest.raises(InputError, match="nobody is listening"):
        open_sink(f"tcp://127.0.0.1:{port}")


@pytest.mark.slow
def test_a_receiver_restarted_mid_call_starts_at_once_from_the_headers_it_kept(tmp_path):
    """The header is never sent again; fd-recv --headers kept it from the call's start."""
    stream, _ = stream_datagrams(smooth_tracks(), eager=0, header_every=0)
    kept = tmp_path / "headers"
    kept.mkdir()
    for run, part in (("first", stream[:10]), ("again", stream[len(stream) // 3:])):
        (tmp_path / run).mkdir()
        proc, port = start_listener("udp://127.0.0.1:0", tmp_path / run, "--headers", str(kept), "--timeout", "0.5")
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            for d in part:
                sock.sendto(d, ("127.0.0.1", port))
        stats, _ = finish(proc)
    assert [p.name for p in kept.iterdir()] == [header().ident.hex() + ".fdheader"]
    seq = np.load(tmp_path / "again" / "recv.npz")["seq"]
    assert seq[0] % KEY == 0 and seq[0] > 0 and stats["concealed"] == 0 and stats["ended"]
    np.testing.assert_array_equal(seq, np.arange(seq[0], N))


def test_the_headers_repeats_are_foreseen_where_they_will_go():
    """The sender's picture layer plans each 2-second window on the header's repeats still to come in it
    (sender/picture_layer.PictureLayer): Datagrams.repeats_ahead says which keyframes will carry one,
    eager or later, before and after the receiver joins, and at every 2nd key place as on a clean link."""
    enc = PacketEncoder(header(), 1)
    head = enc.header()
    pack = Datagrams(head[0], copies=0, header_every=3, eager=5, eager_every=2, key_interval=KEY)
    out = pack.add(head)
    tracks = smooth_tracks(KEY * 20)
    out += pack.add(enc.frame(tracks[0], True))  # place 0
    foreseen = pack.repeats_ahead(range(1, 12))
    for i, x in enumerate(tracks[1:], 1):
        if i == 12 * KEY:  # from place 12 on: joined, keyframes at every 2nd place
            pack.joined, enc.key_every = True, 2
            foreseen += pack.repeats_ahead(range(12, 20, 2))
        out += pack.add(enc.frame(x, True))
    keys = [i for i, d in enumerate(out) if header().ident in d]  # keyframe packets name their header
    sent = [out[k - 1] == head[0] for k in keys[1:]]  # places 1-11, then 12, 14, 16, 18
    # eager past each multiple of 2 up to place 5 (2, 4), then past each multiple of 3 (3, 6, 9, 12, 15, 18)
    assert foreseen == sent == [False, True, True, True, False, True, False, False, True, False, False,
                                True, False, True, True]
