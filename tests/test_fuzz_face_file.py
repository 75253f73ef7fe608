"""Fuzzing the face-file reader: whatever the bytes, decode_face returns a face or raises the project's
own error (one line for the user), never anything else, in bounded memory.

A face file comes from whoever made it, or in-band from the sender, so every byte is untrusted:
the mutations flip and cut bytes anywhere, and give the JSON description's fields values of every
wrong kind and size.
"""

import json
import tracemalloc
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from facedeform.codec.face_file.format import decode_face, encode_face, personal_face
from facedeform.common.errors import FdError
from tests.support import a_person, a_picture_with_a_mouth, a_picture_with_shut_eyes, with_info

#: Bytes any one file may make the reader allocate (a valid seed takes about 0.1 MB; a count that claims
#: 2^31 vertices would take gigabytes). Pixels OpenCV decodes are not traced: image headers bound those.
MEMORY = 32 << 20


def seeds() -> list[bytes]:
    """Valid files: a textured face, one with a reference picture and an open mouth, one with shut eyes
    too, the generic-like one."""
    neutral, texture = a_person()
    person = decode_face(personal_face(neutral, texture))
    with_mouth = encode_face(replace(person, picture=a_picture_with_a_mouth()), picture_format=".png")
    with_eyes = encode_face(replace(person, picture=a_picture_with_shut_eyes()), picture_format=".png")
    return [personal_face(neutral, texture), with_mouth, with_eyes, personal_face(neutral)]


SEEDS = seeds()
FIELDS = ("vertices", "faces", "texture", "meta", "motion", "picture", "projection", "mouth", "mouth_points", "rings",
          "shut_eyes")
WEIRD = st.one_of(
    st.none(), st.booleans(), st.integers(-2**70, 2**70), st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8), st.lists(st.integers(-2**40, 2**40), max_size=5),
    st.lists(st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=5), max_size=5),
    st.dictionaries(st.text(max_size=4), st.integers(), max_size=3),
)


def assert_only_our_errors(data: bytes) -> None:
    tracemalloc.start()
    try:
        decode_face(data, "fuzz")
    except FdError as exc:
        assert str(exc).count("\n") == 0 and str(exc).startswith("fuzz"), str(exc)
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    assert peak < MEMORY


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(range(len(SEEDS))), st.lists(st.tuples(st.integers(0, 2**31), st.integers(1, 255)),
                                                    max_size=8), st.one_of(st.none(), st.integers(0, 2**31)))
def test_flipped_and_cut_bytes_give_only_our_error(seed, flips, cut):
    data = bytearray(SEEDS[seed])
    for where, mask in flips:
        data[where % len(data)] ^= mask
    if cut is not None:
        data = data[:cut % len(data)]
    assert_only_our_errors(bytes(data))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(range(len(SEEDS))), st.dictionaries(st.sampled_from(FIELDS), WEIRD, min_size=1, max_size=3))
def test_wrong_description_values_give_only_our_error(seed, changes):
    assert_only_our_errors(with_info(SEEDS[seed], **changes))


@pytest.mark.parametrize("field, value", [("texture", float("inf")), ("picture", [float("inf"), 16, 16]),
                                          ("motion", [float("-inf"), 1, "rest"]), ("mouth", [float("inf"), 1, 1]),
                                          ("shut_eyes", [float("inf"), 30, 12, 20, 30])])
def test_an_infinite_count_is_our_error(field, value):
    assert_only_our_errors(with_info(SEEDS[2], **{field: value}))


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(range(len(SEEDS))), st.binary(max_size=64), st.integers(0, 2**31))
def test_bytes_inserted_or_a_description_that_is_not_json_give_only_our_error(seed, junk, where):
    data = SEEDS[seed]
    at = where % len(data)
    assert_only_our_errors(data[:at] + junk + data[at:])
    n = int.from_bytes(data[8:12], "little")
    assert_only_our_errors(data[:12] + junk[:n].ljust(n, b"{") + data[12 + n:])


def test_the_seeds_are_faces_and_the_fuzz_is_bounded_in_memory():
    """The mutations start from files that decode, and a whole file of noise is refused at once."""
    assert all(decode_face(s).vertices.shape == (468, 3) for s in SEEDS)
    assert_only_our_errors(np.random.default_rng(0).bytes(len(SEEDS[1])))
    assert_only_our_errors(b"FDFACE\x03\x00" + (1 << 31).to_bytes(4, "little") + json.dumps({}).encode())
