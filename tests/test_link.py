"""The receiver's loss reports and the sender that follows them: copies, and a keyframe at every key place,
only while datagrams are lost."""

import json
import subprocess

import pytest

from facedeform.protocol.framing import PICTURE, SYNC, packet_type
from facedeform.protocol.rate import RateKeeper
from facedeform.protocol.report import SIZE, Report, encode_report, parse_report
from facedeform.protocol.stream import DatagramDecoder, Frame, Picture
from facedeform.sender.config import SendConfig
from facedeform.sender.link import AFTER_LOSS, CLEAN, LEAN_KEYS, QUIET, LinkWatch
from facedeform.sender.session import SendSession
from facedeform.sender.sources import LoopedSource
from tests.support import (
    CLIP,
    DEADLINE,
    ROOT,
    SEND,
    datagrams_per_frame,
    finish,
    largest_window,
    smooth_tracks,
    start_listener,
    stream_datagrams,
)


def test_a_lost_datagram_made_good_by_the_copies_counts_as_repaired_and_a_clean_link_as_nothing():
    datagrams, _ = stream_datagrams(smooth_tracks(), copies=2)
    clean = DatagramDecoder()
    for d in datagrams:
        clean.receive(d)
    assert clean.stats.repaired == clean.stats.concealed == 0
    for lost in (5, 6, 7):  # frames datagrams, one after the keyframe's and after
        lossy = DatagramDecoder()
        frames = [e for d in datagrams[:lost] + datagrams[lost + 1:] for e in lossy.receive(d) if isinstance(e, Frame)]
        assert not any(f.concealed for f in frames)
        assert lossy.stats.repaired == 1, lost
    twice = DatagramDecoder()  # a datagram that comes twice repairs nothing
    for d in datagrams[:6] + datagrams[5:]:
        twice.receive(d)
    assert twice.stats.repaired == 0


def test_a_report_reads_back_and_anything_else_is_not_one():
    report = Report(2 ** 32 + 7, 3, 12, 900, 4)
    data = encode_report(report)
    assert len(data) == SIZE and parse_report(data) == Report(7, 3, 12, 900, 4)
    for junk in (b"", data[:-1], data + b"\0", b"FDLX" + data[4:], data[:4] + b"\x04" + data[5:]):
        assert parse_report(junk) is None
    second = data[:4] + b"\x02" + data[5:-4]  # version 2 says nothing of the picture layer
    first = data[:4] + b"\x01" + data[5:-8]  # version 1 nothing of the face either
    assert parse_report(second) == Report(7, 3, 12, 900, 0) and parse_report(first) == Report(7, 3, 12, None)
    for junk in (second[:4] + b"\x03" + second[5:], first[:4] + b"\x02" + first[5:]):
        assert parse_report(junk) is None
    assert Report(3, 2 ** 32 - 1, 5).lost_since(Report(1, 2 ** 32 - 2, 5)) == 1  # counts wrap
    assert Report(3, 1, 5, None, 2).lost_since(Report(1, 1, 5, None, 1)) == 1  # a picture payload lost


def test_the_link_goes_lean_at_a_clean_report_and_back_at_a_loss_or_when_the_reports_stop():
    now = [0.0]
    watch = LinkWatch(lambda: now[0])
    assert not watch.lean and not watch.heard  # no report: the receiver may not report at all
    watch.hear(Report(CLEAN - 1, 0, 0))
    assert not watch.lean
    watch.hear(None)  # nothing new since the last call
    watch.hear(Report(CLEAN, 0, 0))
    assert watch.lean and watch.heard
    now[0] += QUIET + 0.1  # the reports stopped: the way back may have failed
    assert not watch.lean
    watch.hear(Report(CLEAN + 10, 0, 0))
    assert watch.lean
    watch.hear(Report(CLEAN + 20, 1, 0))  # a packet repaired: the link loses
    assert not watch.lean
    watch.hear(Report(CLEAN + 20 + AFTER_LOSS - 1, 1, 0))
    assert not watch.lean  # once it lost, it must stay clean far longer
    watch.hear(Report(CLEAN + 20 + AFTER_LOSS, 1, 0))
    assert watch.lean
    late = LinkWatch(lambda: now[0])  # a first report with losses in it is a loss
    late.hear(Report(100, 0, 1))
    late.hear(Report(100 + CLEAN, 0, 1))
    assert not late.lean


def test_a_session_drops_its_copies_and_keyframes_while_the_reports_are_clean_and_takes_them_back_at_a_loss():
    heard = []

    def feedback() -> Report:
        heard.append(None)
        n = len(heard)
        return Report(n, max(0, n - 50), 0)  # clean for 50 frames, then a packet repaired each frame

    session = SendSession(str(CLIP), SendConfig(datagrams=True))
    session.feedback = feedback
    decoder, frames, lean_sizes, full_sizes, keys = DatagramDecoder(), [], [], [], {True: 0, False: 0}  # keyframes
    for packets in session.packets():
        frames += [e for p in packets for e in decoder.receive(p) if isinstance(e, Frame)]
        lean = session.datagrams.copies == 0
        (lean_sizes if lean else full_sizes).append(sum(map(len, packets)))
        keys[lean] += sum(session.header.ident in p for p in packets[-1:])  # the frame's own datagram
    assert [f.seq for f in frames] == list(range(75)) and not any(f.concealed for f in frames)
    assert session.lean_frames == 51 - CLEAN  # from the first report to the 50th, the last clean one
    places = session.header.key_interval
    assert keys[True] <= -(-session.lean_frames // (LEAN_KEYS * places)) + 1  # lean: every LEAN_KEYS-th place
    lean = sum(lean_sizes) / session.lean_frames  # bytes a frame, the header aside
    assert lean < 0.6 * sum(full_sizes[1:]) / (75 - session.lean_frames)
    assert session.datagrams.copies == 3 and session.encoder.frames_per_packet == 1 and session.encoder.key_every == 1


def call_over_udp(tmp_path, *receiver_options) -> dict:
    """fd-send's statistics for the bundled clip sent live to fd-recv over loopback UDP, once fd-recv
    has drawn every frame from its data."""
    proc, port = start_listener("udp://127.0.0.1:0", tmp_path, "--timeout", "3", *receiver_options)
    sent = subprocess.run(SEND + [str(CLIP), "--realtime", "--json", "-o", f"udp://127.0.0.1:{port}"],
                          capture_output=True, cwd=ROOT, timeout=DEADLINE)
    assert sent.returncode == 0, sent.stderr.decode()
    stats, _ = finish(proc)
    assert stats["frames"] == stats["written"] == 75 and stats["concealed"] == 0
    return json.loads(sent.stderr.decode().strip().splitlines()[-1])


def test_fd_send_over_udp_sends_lean_while_fd_recv_reports_no_loss(tmp_path):
    """A real receiver on loopback reports; the same call to one told not to (--no-reports) keeps its
    copies. Every frame arrives either way."""
    reported = call_over_udp(tmp_path)
    unreported = call_over_udp(tmp_path, "--no-reports")
    assert unreported["lean_frames"] == 0 and reported["lean_frames"] >= 25
    assert reported["kbit_per_s"] < 0.8 * unreported["kbit_per_s"]


@pytest.mark.parametrize("reports", [True, False])
def test_where_only_a_lean_link_leaves_the_layer_room_it_runs_while_the_reports_are_clean(face, reports):
    """At 6 kbit/s over UDP the parameters with their copies leave the picture layer too little, without
    them enough: it starts once the receiver reports a clean link and stops at its first loss; a
    receiver that does not report never gets it. Every frame is drawn either way."""
    heard, warnings = [], []

    def feedback() -> Report | None:
        heard.append(None)
        n = len(heard)  # the first report after 1 s, clean until 6 s, then a packet repaired each frame
        return Report(n, max(0, n - 150), 0) if n >= 25 else None

    session = SendSession(LoopedSource(str(CLIP), 10.0), SendConfig(bitrate=6000, datagrams=True), face=face,
                          warn=warnings.append)
    if reports:
        session.feedback = feedback
    decoder, frames, layer = DatagramDecoder(), [], []
    for packets in session.packets():
        pictures = sum(packet_type(p[1]) == PICTURE for p in packets if p[0] == SYNC and len(p) > 1)
        layer += [session.frame_count] * pictures
        frames += [e for p in packets for e in decoder.receive(p) if isinstance(e, Frame)]
    assert any("waits until fd-recv reports a link that loses nothing" in w for w in warnings)
    assert len(frames) == 250 and not any(f.concealed for f in frames)
    if reports:
        assert layer and 25 <= layer[0] and layer[-1] <= 151  # from the first clean report to the first loss
        assert session.stats()["picture_packets"] == len(layer)
    else:
        assert not layer and session.stats()["picture_packets"] is None


def test_copies_that_the_rate_cannot_carry_do_not_go():
    """--bitrate is the whole budget over udp:// too: to a receiver that does not report, the bundled clip
    at 3 kbit/s with three copies of each packet would take about 3.5; one goes, fd-send says so once,
    every 2 seconds keep within a tenth of the rate, and every frame still arrives."""
    said: list[str] = []
    session = SendSession(str(CLIP), SendConfig(bitrate=3000, datagrams=True), warn=said.append)
    decoder, frames = DatagramDecoder(), []
    bits = datagrams_per_frame(session, lambda d: frames.extend(e for e in decoder.receive(d) if isinstance(e, Frame)))
    assert session.datagrams.copies < 3 and sum("copies" in line for line in said) == 1
    assert largest_window(bits) <= 1.1 * 3000
    assert [f.seq for f in frames] == list(range(75))


def test_a_copy_fewer_goes_where_the_call_grows_costlier_than_the_rate_at_the_coarsest_level():
    """To a receiver that does not report, the bundled clip at 4 kbit/s keeps its three copies at the
    coarsest level (its first second fits the rate); livelier after it, it would cost more, and the level
    can go no coarser: one copy fewer goes from then on (protocol/rate.RateKeeper.short), fd-send says so
    once, every 2 seconds keep within a tenth of the rate, and every frame still arrives."""
    said: list[str] = []
    session = SendSession(str(CLIP), SendConfig(bitrate=4000, datagrams=True), warn=said.append)
    decoder, frames = DatagramDecoder(), []
    bits = datagrams_per_frame(session, lambda d: frames.extend(e for e in decoder.receive(d) if isinstance(e, Frame)))
    assert session.header.quality == 1 and session.datagrams.copies == 2
    assert len(said) == 1 and "costs more than the 4 kbit/s asked at the coarsest level; 2 go" in said[0]
    assert largest_window(bits) <= 1.1 * 4000
    assert [f.seq for f in frames] == list(range(75))


def test_fewer_keyframes_go_where_the_parameters_without_copies_take_most_of_the_rate():
    """To a receiver that does not report, the bundled clip without a face at 1.5 kbit/s: at the coarsest
    level and without copies, a keyframe at every key place and the header's repeats took its largest
    2-second window to 1.24 times the rate. A keyframe goes at every 4th key place instead (about a
    second), fd-send says so once, every 2 seconds keep within a tenth of the rate, and every frame
    still arrives."""
    said: list[str] = []
    session = SendSession(str(CLIP), SendConfig(bitrate=1500, datagrams=True, embed_face=False), warn=said.append)
    decoder, frames = DatagramDecoder(), []
    bits = datagrams_per_frame(session, lambda d: frames.extend(e for e in decoder.receive(d) if isinstance(e, Frame)))
    assert session.header.quality == 1 and session.datagrams.copies == 0 and session.encoder.key_every == 4
    assert sum("a keyframe goes every 0.96 s instead of every 0.24 s" in line for line in said) == 1
    assert largest_window(bits) <= 1.1 * 1500
    assert [f.seq for f in frames] == list(range(75)) and not decoder.stats.damaged


def test_keyframes_thin_out_mid_call_while_the_coarsest_level_without_copies_is_short(monkeypatch):
    """Where the rate keeper says the coarsest level costs more than the rate (here from the second
    second on, once a second) and no copies are left to shed, a keyframe goes at every 2nd key place,
    then every 4th, never fewer; fd-send says so each time, and every frame still arrives."""
    step, steps = RateKeeper.step, []

    def short_from_the_second_second(keeper, *args):
        zone = step(keeper, *args)
        steps.append(len(steps))
        keeper.short = steps[-1] in (25, 50, 74)
        return zone

    monkeypatch.setattr(RateKeeper, "step", short_from_the_second_second)
    said: list[str] = []
    session = SendSession(str(CLIP), SendConfig(bitrate=1850, datagrams=True, embed_face=False, redundancy=0),
                          warn=said.append)
    decoder, frames, every = DatagramDecoder(), [], []

    def receive(datagram):
        frames.extend(e for e in decoder.receive(datagram) if isinstance(e, Frame))
        every.append(session.encoder.key_every)

    datagrams_per_frame(session, receive)
    assert every[0] == 1 and sorted(set(every)) == [1, 2, 4]
    assert [line.split("; ")[1].split(":")[0] for line in said] == [
        f"a keyframe goes every {gap} s instead of every 0.24 s" for gap in (0.48, 0.96)]
    assert [f.seq for f in frames] == list(range(75)) and not decoder.stats.damaged


def test_the_first_level_leaves_room_for_the_headers_first_repeats():
    """Over udp:// without copies, the bundled clip without a face at 2 kbit/s: the header goes again
    about once a second for the first 4 seconds, for a receiver started just after the sender. Its
    level, chosen from the first second without them, fitted that second to the rate. It was level 3,
    and the second and third seconds took a 2-second window to 1.17 times the rate. With them it is
    the coarsest, and every window keeps within a tenth of the rate."""
    session = SendSession(str(CLIP), SendConfig(bitrate=2000, datagrams=True, embed_face=False, redundancy=0),
                          warn=lambda line: None)
    bits = datagrams_per_frame(session)
    assert session.header.quality == 1 and largest_window(bits) <= 1.1 * 2000


def test_a_session_foresees_the_frames_its_headers_repeats_go_with():
    """What the picture layer plans a window on (SendSession._repeats_ahead): from the first frame, the
    header's repeats over the next 60 frames fall on the frames and with the bits they then take."""
    session = SendSession(str(CLIP), SendConfig(datagrams=True))
    went, foreseen = [], None
    for i, _ in enumerate(session.packets()):
        if i == 1:  # the first frame's datagrams
            foreseen, before = session._repeats_ahead(0, 60), session.datagrams.repeated
        elif i > 1 and len(went) < 60:
            went += [0] * (session.frame_count - 1 - len(went))
            went[-1] += 8 * (session.datagrams.repeated - before)
            before = session.datagrams.repeated
    assert sum(b > 0 for b in went) >= 2 and list(foreseen) == went


def layer_keys(face, loss_from: int) -> list[int]:
    """The frames of the picture layer's keys in the bundled clip at 10 kbit/s over datagrams, the
    receiver reporting every 6th frame, its reports from frame ``loss_from`` on showing a loss."""
    heard = []

    def feedback() -> Report | None:
        heard.append(None)
        n = len(heard)
        return Report(n, int(n >= loss_from), 0) if n % 6 == 0 else None

    session = SendSession(str(CLIP), SendConfig(bitrate=10_000, datagrams=True, embed_face=False), face=face)
    session.feedback = feedback
    decoder = DatagramDecoder()
    return [e.seq for packets in session.packets() for p in packets for e in decoder.receive(p)
            if isinstance(e, Picture) and e.data[0] & 1]


def test_a_reported_loss_brings_the_picture_layer_s_next_key_forward(face):
    """A receiver that lost a packet of the layer draws the model's picture alone until its next key (a
    second after the last over datagrams, at frame 24 here without the ask): the first report of a loss,
    at frame 18, asks for it at once."""
    clean, lossy = layer_keys(face, 10 ** 6), layer_keys(face, 18)
    assert clean[0] == lossy[0] == 0
    assert not [k for k in clean if 0 < k < 25]
    assert [k for k in lossy if 18 <= k <= 20]


def test_a_lost_picture_datagram_is_reported_and_brings_the_layer_s_key_at_once(face):
    """Picture packets travel in datagrams of their own: a receiver that lost one, and nothing else,
    counts it in its reports (protocol/report.py, version 3), and the sender sends the layer's next key
    at once. Before, the frames arriving whole, the link looked clean and the layer stayed lost to the
    end of the call (the clip's 3 s)."""
    from facedeform.api import _Collect
    from facedeform.experiment.reporting import ReportingReceiver
    from facedeform.receiver.session import ReceiveSession

    session = SendSession(str(CLIP), SendConfig(bitrate=10_000, datagrams=True, embed_face=False), face=face)
    link = ReportingReceiver(session, session.header.fps)
    drawing = ReceiveSession(lambda fps, size: [_Collect([])], None, face.model, warn=lambda line: None)
    drawing.counts = link.decoder.stats  # as fd-recv's session counts into its source's decoder
    dropped, keys = None, []
    for datagrams in session.packets():
        for datagram in datagrams:
            if dropped is None and session.frame_count > 8 and packet_type(datagram[1]) == PICTURE:
                dropped = session.frame_count
                continue
            events = link.receive(datagram)
            keys += [e.seq for e in events if isinstance(e, Picture) and e.data[0] & 1]
            drawing.handle(events, 0.0)
    assert dropped is not None and drawing.counts.layer_lost > 0 and drawing.stats(1.0)["picture_lost"] > 0
    assert f"{drawing.counts.layer_lost} picture layer payloads lost" in drawing.summary(1.0)
    assert keys[0] == 0 and [k for k in keys if dropped < k <= dropped + 12]
