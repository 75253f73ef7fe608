"""The binary arithmetic coder: its self-delimiting code decodes exactly and knows its length."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from facedeform.protocol.arith import (
    LARGEST,
    AdaptiveBit,
    Decoder,
    Encoder,
    Incomplete,
    decode_integers,
    decode_run,
    encode_integers,
    encode_run,
)


def code(bits: list[int], models: list[int], first_byte_below: int = 256) -> Encoder:
    """``bits`` coded with ``models[i]`` of three adaptive models (3: at probability 1/2)."""
    enc, shared = Encoder(first_byte_below), [AdaptiveBit(), AdaptiveBit(5, 1), AdaptiveBit(0, 9)]
    for bit, m in zip(bits, models):
        enc.bit(bit, shared[m] if m < 3 else None)
    return enc


def read(dec: Decoder, models: list[int]) -> list[int]:
    shared = [AdaptiveBit(), AdaptiveBit(5, 1), AdaptiveBit(0, 9)]
    return [dec.bit(shared[m] if m < 3 else None) for m in models]


BITS = st.lists(st.tuples(st.integers(0, 1), st.integers(0, 3)), min_size=1, max_size=300)


@settings(max_examples=200, deadline=None)
@given(BITS, st.binary(max_size=12), st.sampled_from([256, 0xFD]))
def test_a_self_delimiting_code_decodes_whatever_follows_it(pairs, after, first_byte_below):
    bits, models = [b for b, _ in pairs], [m for _, m in pairs]
    enc = code(bits, models, first_byte_below)
    data = enc.end()
    assert data and data[0] < first_byte_below
    dec = Decoder(data + after, first_byte_below)
    assert read(dec, models) == bits
    assert dec.end() == data and dec.trace == enc.trace


@settings(max_examples=100, deadline=None)
@given(BITS)
def test_a_self_delimiting_code_cut_short_asks_for_more(pairs):
    """No proper prefix of the code decides all its bits: a decoder waits rather than guess."""
    bits, models = [b for b, _ in pairs], [m for _, m in pairs]
    data = code(bits, models).end()
    for cut in range(len(data)):
        with pytest.raises(Incomplete):
            read(Decoder(data[:cut]), models)


RUNS = st.tuples(st.lists(st.integers(0, 1), max_size=600), st.integers(0, 70), st.integers(0, 70))


@settings(max_examples=300, deadline=None)
@given(RUNS, st.binary(max_size=6), st.integers(0, 1000))
def test_a_compiled_run_codes_and_decodes_as_the_coder_does(run, after, cut):
    """encode_run and decode_run give the exact coder's bytes, bits, lengths and model counts, also
    for a code cut short (None where the coder asks for more) or followed by other bytes."""
    bits, n0, n1 = run
    enc, model = Encoder(), AdaptiveBit(n0, n1)
    for bit in bits:
        enc.bit(bit, model)
    ran = AdaptiveBit(n0, n1)
    assert encode_run(np.array(bits, np.uint8), ran) == enc.end() and (ran.n0, ran.n1) == (model.n0, model.n1)
    for data in (enc.end() + after, (enc.end() + after)[:cut]):
        dec, exact = Decoder(data), AdaptiveBit(n0, n1)
        try:
            want: tuple | None = ([dec.bit(exact) for _ in bits], len(dec.end()))
        except Incomplete:
            want = None
        ran = AdaptiveBit(n0, n1)
        got = decode_run(data, len(bits), ran)
        assert (None if got is None else (got[0].tolist(), got[1])) == want
        if want is not None:
            assert (ran.n0, ran.n1) == (exact.n0, exact.n1)


INTEGERS = st.lists(st.tuples(st.integers(-LARGEST, LARGEST) | st.integers(-3, 3), st.integers(0, 4)), max_size=400)


@settings(max_examples=200, deadline=None)
@given(INTEGERS, st.binary(max_size=6))
def test_integers_decode_exactly_whatever_follows_them(pairs, after):
    values, groups = np.array([v for v, _ in pairs], np.int64), np.array([g for _, g in pairs], np.int64)
    data = encode_integers(values, groups, 5)
    np.testing.assert_array_equal(decode_integers(data + after, groups, 5), values)


def test_integers_take_near_their_entropy_and_larger_ones_are_refused():
    values = np.rint(np.random.default_rng(0).laplace(0, 2, 10_000)).astype(np.int64)
    _, counts = np.unique(values, return_counts=True)
    entropy = -(counts * np.log2(counts / len(values))).sum()  # bits, 3.46 each
    group = np.zeros(len(values), np.int64)
    assert 8 * len(encode_integers(values, group, 1)) < 1.02 * entropy
    assert 8 * len(encode_integers(8 * values, group, 1)) < 1.04 * entropy  # three digits learned to be 0
    with pytest.raises(ValueError):
        encode_integers(np.array([LARGEST + 1]), np.zeros(1, np.int64), 1)


@settings(max_examples=100, deadline=None)
@given(st.binary(max_size=300), st.integers(0, 2_000))
def test_any_bytes_decode_to_integers_within_bounds(data, count):
    values = decode_integers(data, np.arange(count) % 3, 3)
    assert len(values) == count and (count == 0 or np.abs(values).max() <= LARGEST)
