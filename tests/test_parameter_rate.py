"""The parameters kept to a rate: a level from the call's first second, then a dead zone that widens
where the call costs more, and fd-send's default rate with a speaker's own motion basis."""

import numpy as np
import pytest

import facedeform
from facedeform.protocol.encoder import PacketEncoder
from facedeform.protocol.rate import FINER, MOVE, WIDEST, WINDOW, RateKeeper
from facedeform.protocol.stream import DatagramDecoder, Frame, StreamDecoder
from facedeform.sender import session
from facedeform.sender.config import SPEAKER_RATE, SendConfig
from facedeform.sender.session import SendSession
from tests.support import CLIP, clip_frames, datagrams_per_frame, largest_window, sent_per_frame

FPS = 25.0


def test_the_dead_zone_widens_while_the_window_costs_more_and_narrows_back():
    keeper = RateKeeper(1000.0, FPS, narrowest=1.0)
    zones = [keeper.step(80) for _ in range(100)]  # 2000 bit/s: twice the rate
    half = round(WINDOW * FPS) // 2  # a whole window's budget spent in half of it
    assert zones[:half] == [1.0] * half and zones[half] == pytest.approx(1.0 + MOVE)
    assert max(zones) == zones[-1] == WIDEST and all(b >= a for a, b in zip(zones, zones[1:]))
    zones = [keeper.step(0) for _ in range(round(WINDOW * FPS) + 100)]
    assert zones[-1] == 1.0 and min(zones) == 1.0


def test_the_dead_zone_holds_where_the_window_costs_between_slack_and_the_rate():
    keeper = RateKeeper(1000.0, FPS, narrowest=1.0)
    for _ in range(30):
        keeper.step(80)
    zones = [keeper.step(38) for _ in range(200)]  # 950 bit/s
    assert zones[-1] > 1.0 and zones[-150:] == [zones[-1]] * 150


def test_a_first_keyframe_alone_does_not_widen_the_dead_zone():
    """The call's first frame (a key) costs far more than a frame's share; the frames after it, far
    less: the window as a whole stays within the rate, and so does the dead zone."""
    keeper = RateKeeper(1000.0, FPS, narrowest=1.0)
    assert keeper.step(400) == 1.0 and all(keeper.step(10) == 1.0 for _ in range(200))


def test_a_call_dead_zone_wider_than_widest_is_kept():
    keeper = RateKeeper(1000.0, FPS, narrowest=3.5)
    assert keeper.step(10_000) == 3.5 and keeper.step(0) == 3.5


def test_the_level_goes_coarser_a_second_at_a_time_while_the_pace_is_over_the_rate_and_finer_when_well_under():
    """A keeper given the level: at twice the rate one level coarser after the first second, and another
    after the next (the pace taken at each level anew), never below the coarsest, where it says it is
    short once a second; then, a whole window under FINER of the rate at the narrowest zone, one finer
    at a time, never past ``finest``."""
    keeper = RateKeeper(1000.0, FPS, narrowest=1.0, level=4, finest=4)
    levels, short = [], []
    for _ in range(200):
        keeper.step(80)  # 2000 bit/s
        levels.append(keeper.level)
        short.append(keeper.short)
    second = round(FPS)
    assert levels[:second - 1] == [4] * (second - 1) and levels[second - 1] == 3
    assert levels[2 * second - 1] == 2 and min(levels) == levels[-1] == 1
    # at the coarsest, once a second: the caller's to shed what else it can
    assert [i for i, s in enumerate(short) if s] == list(range(4 * second - 1, 200, second))
    for _ in range(1000):
        keeper.step(round(0.5 * FINER * 1000 / FPS))
        levels.append(keeper.level)
    assert levels[-1] == 4 and all(b - a in (0, 1) for a, b in zip(levels[200:], levels[201:]))


def test_the_level_goes_finer_only_where_the_window_has_room_for_what_passes_beside_the_frames_too():
    """Bits that go only for a while (over datagrams, the header's eager repeats at the call's start) keep a
    finer level from being taken that the window cannot pay for, but do not widen the dead zone: a coarser
    level would not save them."""
    keeper = RateKeeper(1000.0, FPS, narrowest=1.0, level=2, finest=4)
    for _ in range(100):  # 250 bit/s of frames, well under FINER of the rate; 1250 more beside them
        assert keeper.step(10, passing=50) == 1.0
    assert keeper.level == 2
    steps = 1
    while keeper.step(10) and keeper.level == 2:
        steps += 1
    # once what passes in the window is under FINER of its 2000 bits less its 500 of frames: 13 frames' worth
    assert FINER == 0.6 and keeper.level == 3 and steps == round(WINDOW * FPS) - 13


def test_a_keeper_without_the_level_leaves_it():
    keeper = RateKeeper(1000.0, FPS, narrowest=1.0)
    assert all(keeper.step(400) and keeper.level is None for _ in range(100))


def test_a_call_livelier_than_its_first_second_goes_a_level_coarser_and_keeps_the_rate(monkeypatch):
    """The bundled clip's speaker is quiet in his first second and talks after it: at 1.5 kbit/s without a
    face, coded all through at the level that fitted his first second (4), a 2-second window took 1.24
    times the rate. A keyframe naming the header a level coarser now goes once the pace passes the rate:
    every window within a tenth of it (as fd-send's own count says too), and every frame decoded as the
    sender reconstructed it."""
    sent = []
    frame = PacketEncoder.frame

    def framed(encoder, *args):  # the call's own frames, not the sample's tries at each level
        packets = frame(encoder, *args)
        if encoder is call.encoder:
            sent.append((encoder.reconstruction, encoder.level))
        return packets

    monkeypatch.setattr(PacketEncoder, "frame", framed)
    call = SendSession(str(CLIP), SendConfig(bitrate=1500, embed_face=False), warn=lambda line: None)
    chunks, bits, _ = sent_per_frame(call)
    assert call.header.quality == 4 and call.stats()["level_changes"] >= 1 and min(level for _, level in sent) < 4
    assert largest_window(bits) <= 1.1 * 1500
    assert call.stats()["costliest_2s_kbit_per_s"] == pytest.approx(largest_window(bits) / 1000, abs=1e-3)
    decoder = StreamDecoder()
    events = decoder.feed(b"".join(chunks)) + decoder.close()
    decoded = [e for e in events if isinstance(e, Frame)]
    assert len(decoded) == len(sent) == clip_frames() and not decoder.stats.damaged
    for f, (r, _) in zip(decoded, sent):
        np.testing.assert_array_equal(f.params, r)


def test_over_datagrams_the_level_moves_at_key_places_and_keeps_the_rate():
    """To a receiver that does not report, the bundled clip at 6 kbit/s without a face, with its copies,
    took a 2-second window to 1.26 times the rate at the level of its quiet first second: the new
    levels' keyframes now go at key places only (the header's repeats keep their pace), every window
    keeps within a tenth of the rate, and every frame arrives."""
    call = SendSession(str(CLIP), SendConfig(bitrate=6000, datagrams=True, embed_face=False), warn=lambda line: None)
    decoder, decoded = DatagramDecoder(), []
    bits = datagrams_per_frame(call, lambda d: decoded.extend(e for e in decoder.receive(d) if isinstance(e, Frame)))
    assert call.stats()["level_changes"] >= 1 and largest_window(bits) <= 1.1 * 6000
    assert call.stats()["costliest_2s_kbit_per_s"] == pytest.approx(largest_window(bits) / 1000, abs=1e-3)
    assert [f.seq for f in decoded] == list(range(clip_frames())) and not decoder.stats.damaged


def send(**options) -> tuple[bytes, float, int]:
    """(the stream, bit/s of what follows its header (the first chunk), the header's quality level)."""
    chunks = list(facedeform.encode(CLIP, embed_face=False, **options))
    decoder = StreamDecoder()
    events = decoder.feed(b"".join(chunks)) + decoder.close()
    header, frames = events[0], sum(isinstance(e, Frame) for e in events)
    return b"".join(chunks), 8 * sum(map(len, chunks[1:])) * header.fps / frames, header.quality


def test_a_rate_below_the_coarsest_level_is_kept_closer_by_the_dead_zone(face):
    """At 0.2 kbit/s the coarsest level is chosen and still costs more; the widened dead zone
    makes the stream smaller than the same level with the call's own."""
    _, kept_rate, kept_level = send(face=face, bitrate=200)
    _, fixed_rate, fixed_level = send(face=face, level=1)
    assert kept_level == fixed_level == 1 and fixed_rate > 200
    assert kept_rate < 0.9 * fixed_rate


def test_with_a_speakers_motion_basis_the_default_is_the_finest_level_within_the_speaker_rate(face, monkeypatch):
    """The sample's speaker codes his first second within LEVEL_SHARE of SPEAKER_RATE at level 4, not
    at 5: the default is level 4, within the rate (the dead zone widened where the call costs more
    than its first second: at most level 4's own rate), where level 5 costs more than the share. A
    speaker that costs more (here: a lower rate to keep) gets a coarser level, the finest whose first
    second fits, and a wider dead zone where the call then costs more than its first second
    (protocol/rate.py: the level alone is not kept to the rate)."""
    _, rate, level = send(face=face)
    assert rate <= SPEAKER_RATE and level == 4 and rate <= send(face=face, level=4)[1]
    assert send(face=face, level=5)[1] > session.LEVEL_SHARE * SPEAKER_RATE
    monkeypatch.setattr(session, "SPEAKER_RATE", rate / 2)
    _, thin, coarser = send(face=face)
    assert coarser < 4 and thin < send(face=face, level=coarser)[1]


def test_a_quality_or_the_generic_face_keeps_a_fixed_level():
    generic, _, level = send()
    assert generic == send(level=3)[0] and level == 3


def test_where_no_picture_layer_runs_the_parameters_aim_at_the_whole_rate(face):
    """At 1.5 kbit/s a layer does not pay: the stream is the same as with the layer off, the
    parameters keeping all of the rate (no share held back for a layer that never comes)."""
    thin, rate, _ = send(face=face, bitrate=1500)
    assert thin == send(face=face, bitrate=1500, picture_layer=False)[0]
    assert rate <= 1500
