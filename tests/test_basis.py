"""The coding basis: principal axes from a sample, carried in the header, and what they save."""


import numpy as np
import pytest

from facedeform.common.errors import BitstreamError
from facedeform.protocol.basis import MIN_MOTION, SCALE, principal_basis
from facedeform.protocol.framing import HEADER, build
from facedeform.protocol.header import encode_header, parse_header
from facedeform.protocol.stream import Frame, Header, PacketEncoder, StreamDecoder, frame_bytes, steps_for

NAMES = ("theta", "v3x", "v3y", "v3z", "v8x", "v8y", "rx", "ry")
POSE = [n in ("rx", "ry") for n in NAMES]
FACE = "cd" * 32


def talking(n: int = 200, seed: int = 0) -> np.ndarray:
    """(n, len(NAMES)): the jaw, lower lip and corners driven by one opening (plus tracker noise), and
    a head that turns on its own."""
    rng = np.random.default_rng(seed)
    steps = steps_for(NAMES)
    opening = 20 * np.sin(np.arange(n) / 3.0) ** 2
    shares = np.array([1.0, 0.1, -0.9, -0.3, 0.2, -0.4, 0.0, 0.0])
    u = opening[:, None] * shares + rng.normal(0, 0.8, (n, len(NAMES)))
    u[:, 6:] = np.cumsum(rng.normal(0, 1.0, (n, 2)), axis=0)
    return u * steps


def header(basis=None) -> Header:
    return Header(25.0, NAMES, steps_for(NAMES), FACE, skip_static=True, basis=basis)


def test_first_axis_is_the_shared_motion_and_pose_keeps_its_own():
    basis = principal_basis(talking(), steps_for(NAMES), POSE)
    assert basis.dtype == np.int8 and basis.shape == (8, 8)
    shares = np.array([1.0, 0.1, -0.9, -0.3, 0.2, -0.4])
    first = basis[0, :6] / SCALE
    assert abs(first @ shares) / np.linalg.norm(shares) > 0.99
    np.testing.assert_array_equal(basis[6:], np.eye(8, dtype=np.int8)[6:] * SCALE)
    np.testing.assert_array_equal(basis[:6, 6:], 0)
    forward = basis / SCALE
    np.testing.assert_allclose(forward @ forward.T, np.eye(8), atol=0.03)  # orthonormal up to rounding


def test_same_sample_same_bytes_and_a_still_face_gets_none():
    sample = talking()
    np.testing.assert_array_equal(principal_basis(sample, steps_for(NAMES), POSE),
                                  principal_basis(sample.copy(), steps_for(NAMES), POSE))
    still = np.random.default_rng(1).normal(0, 0.5 * MIN_MOTION, (25, 8)) * steps_for(NAMES)
    assert principal_basis(still, steps_for(NAMES), POSE) is None
    assert principal_basis(sample[:1], steps_for(NAMES), POSE) is None


def test_a_header_with_a_basis_reads_back():
    basis = principal_basis(talking(), steps_for(NAMES), POSE)
    made = header(basis)
    back = parse_header(encode_header(made))
    assert back == made and back != header()
    np.testing.assert_array_equal(back.basis, basis)


@pytest.mark.parametrize("damage, message", [
    (lambda b: b[:-1], "header length"),
    (lambda b: b[:3] + bytes([b[3] & ~4]) + b[4:], "header length"),  # the basis flag cleared
    (lambda b: b[:-64] + bytes(64), "basis is singular"),
])
def test_a_damaged_basis_is_refused(damage, message):
    body = encode_header(header(principal_basis(talking(), steps_for(NAMES), POSE)))
    with pytest.raises(BitstreamError, match=message):
        StreamDecoder().feed(build(HEADER, damage(body)))


def code(h: Header, params: np.ndarray) -> tuple[int, np.ndarray]:
    """(stream bytes after the header, decoded parameters) at a dead zone of 1."""
    enc = PacketEncoder(h, 2, dead_zone=1.0)
    head, body = frame_bytes(enc.header()), b""
    for x in params:
        body += frame_bytes(enc.frame(x, True))
    body += frame_bytes(enc.end())
    dec = StreamDecoder()
    got = [e.params for e in dec.feed(head + body) + dec.close() if isinstance(e, Frame)]
    return len(body), np.array(got)


def test_correlated_motion_costs_fewer_bits_along_its_axes_for_about_the_same_error():
    params = talking(300, seed=2)
    basis = principal_basis(params[:25], steps_for(NAMES), POSE)  # the first second, as fd-send does
    plain_bytes, plain = code(header(), params)
    coded_bytes, coded = code(header(basis), params)
    assert coded_bytes < 0.92 * plain_bytes  # measured 0.86-0.89 over five seeds
    rms = [np.sqrt(np.mean(((got - params) / steps_for(NAMES)) ** 2)) for got in (plain, coded)]
    assert rms[1] < 1.2 * rms[0]
