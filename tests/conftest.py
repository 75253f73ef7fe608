"""Fixtures shared by the test modules; plain helpers are in tests/support.py.

Tests that take more than a few seconds are marked ``slow`` (``pytest -m "not slow"`` for a quick run).
"""

import numpy as np
import pytest

import facedeform
from tests.support import CLIP, SEND, run


@pytest.fixture(scope="session")
def face():
    """The sample clip's speaker enrolled once (reference picture and a motion basis from 2 s)."""
    return facedeform.enroll(str(CLIP), motion_seconds=2.0)


@pytest.fixture(scope="session")
def enrolled_3s():
    """The sample clip's speaker enrolled from 3 s without a motion basis: the window holds his widest
    open mouth and his blinks (frames 43-44 and 50-53)."""
    return facedeform.enroll(str(CLIP), seconds=3.0, motion=0).model


@pytest.fixture(scope="session")
def sent(tmp_path_factory):
    """The sample clip sent once at fd-send's defaults: (stream bytes, sender dump)."""
    tmp = tmp_path_factory.mktemp("sent")
    result = run(SEND + [str(CLIP), "--dump", str(tmp / "send.npz")])
    assert result.returncode == 0, result.stderr.decode()
    return result.stdout, np.load(tmp / "send.npz")
