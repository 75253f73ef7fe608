"""The abstract levels (expression -> AU -> parameters) and the fd-animate command."""

from __future__ import annotations

import json

import numpy as np
import pytest
from numpy.testing import assert_allclose

from facedeform.codec.model.deform import Deformer
from facedeform.codec.model.expressions import (
    AU_FILE,
    EXPRESSION_FILE,
    au_params,
    default_tables,
    expression_params,
    load_tables,
)
from facedeform.codec.model.face_model import load_base_face
from facedeform.common.errors import InputError
from facedeform.common.parameters import EXTENDED_PARAMS
from facedeform.receiver.animate import interpolate, main

FACE = load_base_face()
DEF = Deformer(FACE)
X = FACE.vertices
IDX = {n: i for i, n in enumerate(EXTENDED_PARAMS)}
TABLES = default_tables()
BROWS = [p["landmark"] for p in FACE.meta["upper_face"]["feature_points"].values() if p["role"] == "brow"]


def test_tables_cover_the_brief():
    assert {1, 2, 4, 5, 6, 7, 9, 10, 12, 15, 16, 17, 18, 20, 22, 23, 24, 25, 26, 27, 43, 45} <= set(TABLES.aus)
    names = {"neutral", "smile", "surprise", "anger", "sadness", "disgust", "fear",
             "rest", "AA", "EE", "OO", "MBP", "FV", "TH_L", "S_Z"}
    assert names <= set(TABLES.expressions)


@pytest.mark.parametrize("name", list(TABLES.expressions))
def test_every_expression_gives_finite_params(name):
    p = expression_params(name)
    assert p.shape == (len(EXTENDED_PARAMS),) and np.isfinite(p).all()
    assert np.isfinite(DEF.deform_extended(p)).all()


def test_neutral_is_zero_and_intensity_scales():
    assert not expression_params("neutral").any() and not expression_params("rest").any()
    assert_allclose(expression_params("surprise", 0.5), 0.5 * expression_params("surprise"))


def test_smile_raises_and_widens_mouth_corners():
    out = DEF.deform_extended(expression_params("smile"))
    assert out[291, 0] - out[61, 0] > X[291, 0] - X[61, 0] + 0.04
    assert (out[[291, 61], 1] > X[[291, 61], 1] + 0.02).all()


def test_surprise_raises_brows_and_opens_jaw():
    p = expression_params("surprise")
    out = DEF.deform_extended(p)
    assert p[IDX["theta"]] > 5 and (out[BROWS, 1] > X[BROWS, 1] + 0.005).all()
    assert out[13, 1] - out[14, 1] > X[13, 1] - X[14, 1] + 0.05


def test_blink_and_visemes():
    assert expression_params("blink")[[IDX["lid_l"], IDX["lid_r"]]].tolist() == [1.0, 1.0]
    gap = lambda name: DEF.deform_extended(expression_params(name))[[13, 14], 1] @ [1, -1]  # noqa: E731
    assert gap("AA") > gap("OO") > gap("rest") > gap("MBP") and abs(gap("MBP")) < 0.005
    width = lambda name: np.ptp(DEF.deform_extended(expression_params(name))[[61, 291], 0])  # noqa: E731
    assert width("EE") > width("rest") > width("OO")


def test_au_vector_is_the_weighted_sum_and_lids_clip():
    assert_allclose(au_params({"12": 0.5, 6: 1}), 0.5 * TABLES.aus[12][1] + TABLES.aus[6][1])
    assert au_params({45: 1, 7: 1})[IDX["lid_l"]] == 1.0


def test_unknown_names_raise_one_line_errors():
    with pytest.raises(InputError, match=r"unknown expression 'grin' \(known: neutral, smile") as exc:
        expression_params("grin")
    assert "\n" not in str(exc.value)
    with pytest.raises(InputError, match="unknown AU 99"):
        au_params({99: 1.0})


@pytest.mark.parametrize("au_text, expr_text", [
    ("{", None),
    ('{"aus": []}', None),
    ('{"aus": {"1": {"params": {"frown": 1}}}}', None),
    ('{"aus": {"x": {"params": {}}}}', None),
    ('{"aus": {"1": {"params": {"theta": "big"}}}}', None),
    (None, '{"expressions": {"smile": {"999": 1}}}'),
    (None, '{"expressions": {"smile": 3}}'),
    (None, '[]'),
])
def test_malformed_tables_raise_input_error(tmp_path, au_text, expr_text):
    au, ex = tmp_path / "au.json", tmp_path / "ex.json"
    au.write_text(au_text if au_text is not None else AU_FILE.read_text())
    ex.write_text(expr_text if expr_text is not None else EXPRESSION_FILE.read_text())
    with pytest.raises(InputError) as exc:
        load_tables(au, ex)
    assert "\n" not in str(exc.value)


def test_interpolation_hits_keys_and_eases():
    times, keys = np.array([0.0, 1.0]), np.array([[0.0], [2.0]])
    assert interpolate(times, keys, 0.0)[0] == 0 and interpolate(times, keys, 1.0)[0] == 2
    assert interpolate(times, keys, 0.5)[0] == pytest.approx(1.0)
    assert interpolate(times, keys, 0.1)[0] < 0.2  # slow start


def _frames(path) -> tuple[bytes, int]:
    data = path.read_bytes()
    return data.split(b"\n", 1)[0], data.count(b"FRAME\n")


@pytest.mark.parametrize("script", ["0.0 neutral\n0.5 smile 0.8 blink\n1.0 AA  # open\n",
                                    json.dumps([{"time": 0, "expression": "neutral"},
                                                {"time": 0.4, "aus": {"12": 1}},
                                                {"time": 1.0, "expression": "OO", "intensity": 0.5}])])
def test_fd_animate_writes_fps_times_duration_frames(tmp_path, script):
    src, out = tmp_path / "anim.txt", tmp_path / "out.y4m"
    src.write_text(script)
    assert main([str(src), "-o", str(out), "--size", "64", "--fps", "10", "-q"]) == 0
    header, count = _frames(out)
    assert count == 10 and b"W64 H64 F10:1" in header


@pytest.mark.parametrize("script, message", [
    (None, "cannot read"),
    ("0.0 neutral\n0.5 grin\n", "unknown expression 'grin'"),
    ("0.0 neutral\nsoon smile\n", "malformed"),
    ("0.0 neutral\n", "at least two keys"),
    ("0.5 smile\n0.2 neutral\n", "increasing"),
    ('[{"time": 0}]', "malformed"),
])
def test_fd_animate_bad_script_one_line_error(tmp_path, capsys, script, message):
    src = tmp_path / "anim.txt"
    if script is not None:
        src.write_text(script)
    assert main([str(src), "-o", str(tmp_path / "out.y4m")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("fd-animate: ") and message in err and err.count("\n") == 1


def test_text_scripts_take_action_units_as_json_does(tmp_path):
    from facedeform.receiver.animate import read_script

    text, json_twin = tmp_path / "a.txt", tmp_path / "a.json"
    text.write_text("0 neutral\n1 AU12 0.8 AU6 0.5 blink\n2 smile\n")
    json_twin.write_text('[{"time": 0, "expression": "neutral"}, {"time": 1, "aus": {"12": 0.8, "6": 0.5}},'
                         ' {"time": 2, "expression": "smile"}]')
    times, keys = read_script(str(text))
    times_json, keys_json = read_script(str(json_twin))
    np.testing.assert_array_equal(times, times_json)
    np.testing.assert_allclose(keys[1], keys_json[1] + expression_params("blink"))
    np.testing.assert_allclose(keys[2], keys_json[2])
