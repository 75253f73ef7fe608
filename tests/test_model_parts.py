"""The in-band face model put together from chunks in any order (protocol/model_parts.py)."""

import random

import pytest

from facedeform.protocol.model_parts import MAX_PIECES, ModelParts


@pytest.mark.parametrize("seed", range(5))
def test_chunks_in_any_order_and_again_make_the_model_each_byte_once(seed):
    rng = random.Random(seed)
    data = bytes(rng.randrange(256) for _ in range(5000))
    parts, held = ModelParts(len(data)), bytearray(len(data))
    while not parts.whole:
        start = rng.randrange(len(data))
        end = min(len(data), start + rng.randint(1, 400))
        assert parts.add(start, data[start:end]) == (0 in held[start:end])  # False: nothing new
        held[start:end] = b"\1" * (end - start)
        assert parts.held == sum(held)
        first_gap = held.find(0)
        assert parts.missing == (len(data) if first_gap < 0 else first_gap)
        assert parts.bytes(parts.missing) == data[:parts.missing]
    assert parts.bytes() == data


def test_a_chunk_outside_the_model_or_one_piece_too_many_is_refused():
    parts = ModelParts(10 * MAX_PIECES)
    assert parts.add(10 * MAX_PIECES - 5, b"123456") is None and parts.add(0, b"") is None
    for i in range(MAX_PIECES):  # a byte every 10: as many separate pieces as are held at once
        assert parts.add(10 * i + 5, b"x")
    assert parts.add(1, b"y") is None  # one more piece
    assert parts.add(6, b"yyyy") is True  # joins a piece: no more pieces
    with pytest.raises(ValueError, match="not all held"):
        parts.bytes(1)
