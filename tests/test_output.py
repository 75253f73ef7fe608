"""Frame sinks: Y4M that parses, H.264 files with the right frame count and rate."""

import io
import re

import av
import numpy as np
import pytest

from facedeform.common.errors import InputError
from facedeform.receiver.output import open_writer
from tests.support import parse_y4m


def frames(n, size=(64, 48)):
    w, h = size
    for i in range(n):
        img = np.zeros((h, w, 3), np.uint8)
        img[:, : (i * 7) % w] = (200, 120, 60)
        yield img


def test_y4m_on_a_stream_parses():
    out = io.BytesIO()
    writer = open_writer("-", 25.0, (64, 48), out)
    for f in frames(5):
        writer.write(f)
    writer.close()
    fields, count = parse_y4m(out.getvalue())
    assert count == 5
    assert (fields[b"W"], fields[b"H"], fields[b"F"], fields[b"C"]) == (b"64", b"48", b"25:1", b"420jpeg")


def test_y4m_keeps_ntsc_rates_exact():
    out = io.BytesIO()
    open_writer("-", 30000 / 1001, (16, 16), out).close()
    assert re.search(rb" F30000:1001 ", out.getvalue())


def test_mp4_has_every_frame_at_the_rate(tmp_path):
    path = tmp_path / "out.mp4"
    writer = open_writer(str(path), 25.0, (64, 48), None)
    for f in frames(30):
        writer.write(f)
    writer.close()
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        decoded = list(container.decode(stream))
        assert stream.codec_context.name == "h264"
        assert float(stream.average_rate) == pytest.approx(25.0)
    assert len(decoded) == 30
    assert decoded[0].width == 64 and decoded[0].height == 48


@pytest.mark.parametrize("target", ["out.avi", "out.txt"])
def test_unknown_output_type_is_refused(tmp_path, target):
    with pytest.raises(InputError, match="unknown output type"):
        open_writer(str(tmp_path / target), 25.0, (64, 48), None)


def test_unwritable_output_is_refused(tmp_path):
    with pytest.raises(InputError, match="cannot write"):
        open_writer(str(tmp_path / "missing-dir" / "out.y4m"), 25.0, (64, 48), None)
