"""Face model, region map and the paper's deformation (section 3.1)."""

from __future__ import annotations

from itertools import combinations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from facedeform.codec.model.deform import PRESETS, Deformer, extended_params
from facedeform.codec.model.face_model import content_id, load_base_face
from facedeform.codec.model.regions import FEATURE_NAMES, RULES, project_weights, round_lower_lip
from facedeform.common.errors import InputError
from facedeform.common.parameters import PAPER_PARAMS

FACE = load_base_face()
DEF = Deformer(FACE)
DEFS = {rule: Deformer(FACE, rule) for rule in RULES}
X = FACE.vertices
FP = FACE.feature_points
FIXED = [FP[n] for n in ("F1", "F5", "F6", "F7", "F10", "F11", "F12", "F13")]
UPPER = [78, 191, 80, 81, 82, 13, 312, 311, 310, 415, 308]
LOWER = [78, 95, 88, 178, 87, 14, 317, 402, 318, 324, 308]

params_st = st.tuples(
    st.floats(-20, 30),
    *[st.floats(-0.08, 0.08) for _ in range(12)],
).map(np.array)


def linear(params: np.ndarray, f3_with_jaw: bool = False) -> np.ndarray:
    """The refined rule's blend of params (13,), before its fold guard."""
    return DEF.blend(extended_params(PAPER_PARAMS, params), f3_with_jaw)


def test_units_and_axes():
    assert X.shape == (468, 3) and FACE.faces.shape == (898, 3) and FACE.faces.dtype == np.int32
    assert_allclose(X[10, 1] - X[152, 1], 1.0)  # forehead top to chin = 1
    assert X[263, 0] > 0 > X[33, 0]  # +x is the face's own left eye
    assert X[FP["F8"], 0] > 0 and X[1, 2] > X[234, 2]  # F8 at +x; nose toward the viewer
    assert FACE.mouth_faces.sum() == 18 and FACE.eye_faces.sum() == 28


@pytest.mark.parametrize("rule", RULES)
def test_zero_params_identity(rule):
    for f3 in (False, True):
        assert_allclose(DEFS[rule].deform(np.zeros(13), f3), X, rtol=0, atol=1e-15)


@pytest.mark.parametrize("rule", RULES)
@settings(max_examples=40, deadline=None)
@given(params=params_st, f3=st.booleans())
def test_fixed_points_never_move(rule, params, f3):
    assert_allclose(DEFS[rule].deform(params, f3)[FIXED], X[FIXED], rtol=0, atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(params_st, st.booleans())
def test_free_points_follow_their_vectors(params, f3):
    """...by the vectors drawn: those sent, unless the fold guard scaled them back (test_deform_rule)."""
    out = DEF.deform(params, f3)
    params = DEF.unfold(extended_params(PAPER_PARAMS, params), f3)[:13]
    for k, name in enumerate(("F2", "F3", "F8", "F9")):
        if name == "F3" and f3:
            want = DEF.rotate_jaw(X[[FP["F3"]]], params[0])[0]
        else:
            want = X[FP[name]] + params[1 + 3 * k : 4 + 3 * k]
        assert_allclose(out[FP[name]], want, atol=1e-12)
    for name in ("F4", "F14", "F15"):
        assert_allclose(out[FP[name]], DEF.rotate_jaw(X[[FP[name]]], params[0])[0], atol=1e-12)


@pytest.mark.parametrize("rule", RULES)
@settings(max_examples=30, deadline=None)
@given(theta=st.floats(-30, 30), params=params_st)
def test_the_jaw_turns_whatever_the_lips_do(rule, theta, params):
    """Each jaw vertex turns about its pivot whatever the lips do, the hinge points stay; by the paper's
    rule the jaw moves rigidly about the axis F12-F13."""
    deformer = DEFS[rule]
    params = np.r_[theta, params[1:]]
    out = deformer.deform(params)
    jaw = np.flatnonzero(deformer.regions.jaw)
    assert len(jaw) > 10
    drawn = deformer.unfold(extended_params(PAPER_PARAMS, params))[0]  # as the fold guard left it
    assert_allclose(out[jaw], deformer.rotate_jaw(X[jaw], drawn), atol=1e-12)
    hinges = [FP["F12"], FP["F13"]]
    assert_allclose(out[hinges], X[hinges], atol=1e-12)
    if rule == "paper":
        before = np.linalg.norm(X[jaw, None] - X[None, jaw], axis=2)
        after = np.linalg.norm(out[jaw, None] - out[None, jaw], axis=2)
        assert_allclose(after, before, atol=1e-12)


def test_an_opening_jaw_lowers_the_chin_more_than_it_draws_it_back():
    """By the refined rule the chin turns about a pivot below the hinge axis (deform.HINGE_DROP): at
    10 degrees it goes down 0.073 and back 0.029 (the paper's, about the mesh's rim: 0.067 and 0.091)."""
    for rule in RULES:
        chin = DEFS[rule].rotate_jaw(X[[FP["F4"], 152]], 10.0) - X[[FP["F4"], 152]]  # its front and its foot
        assert (chin[:, 1] < -0.05).all() and (chin[:, 2] < 0).all()
        back = chin[:, 2] / chin[:, 1]  # back per down
        assert (back < 0.6).all() if rule == "refined" else (back > 1.0).all()


def test_hinge_axis_opens_mouth():
    origin, axis = DEF.hinge_axis
    assert_allclose(np.linalg.norm(axis), 1.0)
    chin = DEF.rotate_jaw(X[[FP["F4"], 152]], 10.0)
    assert (chin[:, 1] < X[[FP["F4"], 152], 1]).all()


@settings(max_examples=40, deadline=None)
@given(params_st, params_st, st.floats(-3, 3))
def test_superposition_without_jaw(a, b, s):
    """Equation (2) is linear in the vectors (before the refined rule's fold guard)."""
    a[0] = b[0] = 0.0
    disp = lambda p: linear(p) - X  # noqa: E731
    assert_allclose(disp(a + s * b), disp(a) + s * disp(b), atol=1e-12)


def _shared_edges():
    tris = [tuple(t) for t in DEF.regions.triangles]
    for (i, a), (j, b) in combinations(enumerate(tris), 2):
        edge = sorted(set(a) & set(b))
        if len(edge) == 2:
            yield i, j, edge


def blend(points: np.ndarray, region: int, rule: str) -> np.ndarray:
    """(k, 15) weights the rule gives points (k, 3) seen in stretch region ``region``: the
    projection weights of equation (1), then the refined rule's rounding."""
    tri = DEF.regions.triangles[region]
    rows = np.zeros((len(points), len(FEATURE_NAMES)))
    rows[:, tri] = project_weights(points, X[[FP[FEATURE_NAMES[t]] for t in tri]], DEF.regions.origin)
    if rule == "refined":
        round_lower_lip(rows)
    return rows


@pytest.mark.parametrize("rule", RULES)
def test_the_weights_in_use_are_the_rule_applied_to_equation_1(rule):
    """Every covered vertex off the inner lips (the refined rule's slit moves those) has exactly
    the weights :func:`blend` gives, so the border tests below test the matrix the deformer uses."""
    regions = DEFS[rule].regions
    loops = FACE.meta["loops"]
    lips = set(loops["inner_lip_upper"]) | set(loops["inner_lip_lower"]) if rule == "refined" else set()
    checked = 0
    for i in np.flatnonzero(regions.covered & ~regions.jaw):
        if i not in lips:
            assert_allclose(regions.weights[i], blend(X[[i]], regions.region[i], rule)[0], atol=1e-12)
            checked += 1
    assert checked > 300


@pytest.mark.parametrize("rule", RULES)
@settings(max_examples=20, deadline=None)
@given(params=params_st, f3=st.booleans())
def test_continuity_across_region_borders(rule, params, f3):
    """Points on the border between two regions (the plane through O and the shared edge) get
    the same displacement from either region's weights, as the rule computes them."""
    vec, _ = DEFS[rule].feature_vectors(params, f3)
    fpos = X[[FP[n] for n in FEATURE_NAMES]]
    o = DEF.regions.origin
    t = np.linspace(0.05, 0.95, 7)[:, None]
    pairs = list(_shared_edges())
    assert len(pairs) >= 25
    for i, j, (a, b) in pairs:
        on_edge = fpos[a] + t * (fpos[b] - fpos[a])
        scales = np.array([0.97, 1.0, 1.03])[:, None, None]  # along the rays from O
        pts = (o + (on_edge - o) * scales).reshape(-1, 3)
        assert_allclose(blend(pts, i, rule) @ vec, blend(pts, j, rule) @ vec, atol=1e-12)
    # Jaw border: on the boundary edges the blend equals the jaw's own turn (affine in the point).
    for a, b in (("F12", "F14"), ("F14", "F4"), ("F4", "F15"), ("F15", "F13")):
        ia, ib = FEATURE_NAMES.index(a), FEATURE_NAMES.index(b)
        on_edge = fpos[ia] + t * (fpos[ib] - fpos[ia])
        rows = np.zeros((len(on_edge), len(FEATURE_NAMES)))
        rows[:, ia], rows[:, ib] = 1 - t[:, 0], t[:, 0]
        if rule == "refined":
            round_lower_lip(rows)
        assert_allclose(rows @ vec, DEFS[rule].rotate_jaw(on_edge, params[0]) - on_edge, atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(params_st, st.booleans(), st.integers(0, 12))
def test_small_change_small_motion(params, f3, k):
    eps = 1e-6
    step = np.zeros(13)
    step[k] = eps
    moved = np.abs(linear(params + step, f3) - linear(params, f3)).max()
    origin, axis = DEF.hinge_axis
    rel = X - origin
    radius = np.linalg.norm(rel - np.outer(rel @ axis, axis), axis=1).max()
    bound = eps * (radius * np.pi / 180 if k == 0 else 1.0)
    assert moved <= bound * 1.001 + 1e-12


def test_weights_partition_of_unity_and_mouth_slit():
    w = DEF.regions.weights
    stretch = ~DEF.regions.jaw
    assert_allclose(w[stretch].sum(axis=1), 1.0)
    assert (w >= 0).all() and (w[DEF.regions.jaw] == 0).all()
    f2, f3 = FEATURE_NAMES.index("F2"), FEATURE_NAMES.index("F3")
    assert (w[UPPER[1:-1], f3] == 0).all()  # upper lip never follows F3
    assert (w[LOWER[1:-1], f2] == 0).all()  # lower lip never follows F2


@pytest.mark.parametrize("loop, point", [(UPPER, "F2"), (LOWER, "F3")])
def test_each_lip_follows_its_midpoint_more_the_nearer_it_is(loop, point):
    """No saw of skin teeth on an opening mouth: along the inner lip, corner to midpoint, the
    midpoint's weight never falls (the slit's thin triangles gave 0.24, 0.31, 0.56, 0.18, 1)."""
    w = DEF.regions.weights[loop, FEATURE_NAMES.index(point)]
    half = len(loop) // 2
    assert w[half] == pytest.approx(1.0)
    assert (np.diff(w[:half + 1]) > 0).all() and (np.diff(w[half:]) < 0).all()


def test_the_refined_lower_lip_follows_f3_off_the_inner_lip():
    """The refined rule rounds F3's weight on the lower lip's body (outer lip midpoint 17, lip
    between it and the corners) and keeps the paper's blend on the inner lip, where rounding
    folded the corners over."""
    f3 = FEATURE_NAMES.index("F3")
    refined, paper = DEFS["refined"].regions.weights[:, f3], DEFS["paper"].regions.weights[:, f3]
    body = [17, 314, 84, 405, 181]
    assert (refined[body] > paper[body] + 0.15).all()
    inner = DEFS["refined"].regions.weights[LOWER[1:-1]]
    assert inner[:, FEATURE_NAMES.index("F4")].max() < 0.02  # so the rounding barely acts there:
    once_more = inner.copy()
    round_lower_lip(once_more)
    assert_allclose(once_more[:, f3], inner[:, f3], atol=0.005)


def test_fig7_opens_mouth_with_theta():
    params, f3 = PRESETS["fig7"]
    gaps = []
    for theta in (0.0, 5.0, 10.0, 15.0):
        out = DEF.deform(np.r_[theta, params[1:]], f3)
        gaps.append(out[13, 1] - out[14, 1])
    assert np.all(np.diff(gaps) > 0.01)
    out = DEF.deform(params, f3)
    assert out[152, 1] < X[152, 1] - 0.03  # the chin drops


def test_fig8_parts_lips_and_narrows():
    out = DEF.deform(*PRESETS["fig8"])
    assert_allclose((out[13, 1] - out[14, 1]) - (X[13, 1] - X[14, 1]), 0.08, atol=1e-12)
    assert out[291, 0] - out[61, 0] < X[291, 0] - X[61, 0] - 0.1


def test_fig9_widens_and_raises_corners():
    out = DEF.deform(*PRESETS["fig9"])
    assert out[291, 0] - out[61, 0] > X[291, 0] - X[61, 0] + 0.07
    assert (out[[291, 61], 1] > X[[291, 61], 1] + 0.03).all()
    assert_allclose(out[[13, 14]], X[[13, 14]], atol=1e-12)


def test_neutral_preset_and_param_names():
    assert len(PAPER_PARAMS) == 13 and PAPER_PARAMS[0] == "theta"
    assert_allclose(DEF.deform(*PRESETS["neutral"]), X, atol=1e-15)


@pytest.mark.parametrize("shape", [(12,), (14,), (1, 13), (2, 13), ()])
def test_wrong_param_shape_raises(shape):
    with pytest.raises(ValueError):
        DEF.deform(np.zeros(shape))


def test_missing_base_face_raises_input_error(tmp_path):
    with pytest.raises(InputError):
        load_base_face(tmp_path / "nowhere")
    with pytest.raises(InputError):
        load_base_face(tmp_path)  # exists but holds no mesh


def test_content_id_stable_and_sensitive():
    again = load_base_face()
    assert again.content_id == FACE.content_id and len(FACE.content_id) == 64
    v = X.copy()
    v[100, 0] += 1e-9
    assert content_id(X, FACE.faces, FACE.meta) == FACE.content_id
    assert content_id(v, FACE.faces, FACE.meta) != FACE.content_id
    assert content_id(X, FACE.faces, {**FACE.meta, "projection_centre_O": [0.0, 0.0, -1.0]}) != FACE.content_id


def test_feature_triangles_do_not_overlap_seen_from_o():
    fpos = X[[FP[n] for n in FEATURE_NAMES]]
    inside = np.stack(
        [np.nan_to_num(project_weights(X, fpos[t], DEF.regions.origin), nan=-1).min(axis=1) > 1e-6
         for t in DEF.regions.triangles]
    )
    assert inside.sum(axis=0).max() <= 1
