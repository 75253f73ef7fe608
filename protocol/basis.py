"""A decorrelating basis: the encoder codes principal components of the parameters, not the parameters.

In speech the jaw, the lips and the mouth corners move together, so the
parameters are strongly correlated: on the dev clips two or three components
carry most of the motion. Coded along the principal axes (in quantiser steps),
the encoder's dead zone holds the minor components still, where per parameter
every small share of a large motion costs bits. The error stays a dead zone in
coded units, the same size as before (an orthonormal basis keeps lengths).

The axes come from a sample of the call itself: the sender holds its first
second anyway to find the rest face. They travel in the header as signed
bytes (1/127 per unit), so both ends use exactly the same matrix; the encoder
inverts the rounded matrix, so rounding costs nothing but a slightly
non-orthonormal basis. Head pose is left on its own axes: a head that keeps
still in the first second and turns later would otherwise spread each turn
over many components. Measured gains are in docs/bitstream.md.
"""

from collections.abc import Sequence

import numpy as np

#: The header carries each entry as a signed byte, this many per unit.
SCALE = 127
#: Steps (rms) the sample's largest component must move for its axes to mean anything: below it the
#: sample is a still face, its axes are the tracker's noise, and a later motion would be spread over
#: many of them (a random rotation costs the `mouth` layout 18 % more bits on the dev clips).
MIN_MOTION = 2.0
#: Largest condition number of a basis the encoder can invert without losing precision.
MAX_CONDITION = 1e3


def principal_basis(sample: np.ndarray, steps: np.ndarray, apart: Sequence[bool]) -> np.ndarray | None:
    """(k, k) int8 basis (rows: coded axes, in steps) from ``sample`` (n, k) parameters, with the
    parameters marked in ``apart`` (k,) on axes of their own; None if the sample hardly moves.

    Rows are in order of falling variance, each with its largest entry positive, so the same
    sample always gives the same bytes.
    """
    sample = np.asarray(sample, dtype=np.float64)
    k = len(steps)
    joint = np.flatnonzero(~np.asarray(apart, dtype=bool))
    if sample.ndim != 2 or sample.shape[1] != k or len(sample) < 2 or len(joint) < 2:
        return None
    u = sample[:, joint] / steps[joint]
    variance, axes = np.linalg.eigh(np.cov(u, rowvar=False))
    if np.sqrt(max(variance[-1], 0.0)) < MIN_MOTION:
        return None
    axes = axes[:, ::-1].T  # rows, largest variance first
    axes *= np.sign(axes[np.arange(len(axes)), np.abs(axes).argmax(axis=1)])[:, None]
    basis = np.eye(k)
    basis[np.ix_(joint, joint)] = axes
    return np.rint(basis * SCALE).astype(np.int8)


def basis_matrices(basis: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(forward (k, k), inverse (k, k)) float64 of an int8 ``basis``; BitstreamError if it is not
    a (k, k) basis the encoder can invert; ValueError if it is not (parse_header reports that as damage)."""
    basis = np.asarray(basis)
    if basis.shape != (k, k) or basis.dtype != np.int8:
        raise ValueError(f"basis must be a ({k}, {k}) int8 matrix")
    forward = basis.astype(np.float64) / SCALE
    if not np.linalg.cond(forward) < MAX_CONDITION:
        raise ValueError("basis is singular")
    return forward, np.linalg.inv(forward)
