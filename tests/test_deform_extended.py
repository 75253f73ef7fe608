"""The upper face beyond the paper (brows, lids, cheeks, gaze) and the head pose of deform_extended."""

from __future__ import annotations

from itertools import combinations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from facedeform.codec.model.deform import Deformer
from facedeform.codec.model.face_model import load_base_face
from facedeform.codec.model.regions import project_weights
from facedeform.codec.model.upper_face import gaze_direction
from facedeform.common.parameters import (
    BASIS_PARAMS,
    BODY_PARAMS,
    EXTENDED_PARAMS,
    GLOBAL_PARAMS,
    MOUTH_PARAMS,
    PAPER_PARAMS,
    UPPER_PARAMS,
)

FACE = load_base_face()
DEF = Deformer(FACE)
X = FACE.vertices
N = len(EXTENDED_PARAMS)
UF = FACE.meta["upper_face"]["feature_points"]
FIXED_LM = [FACE.feature_points[n] for n in ("F1", "F5", "F6", "F7", "F10", "F11", "F12", "F13")] + [
    p["landmark"] for p in UF.values() if p["role"] == "fixed"]
LIDS = [(p["landmark"], p["closes_to"], p["side"]) for p in UF.values() if p["role"] == "lid"]
IDX = {n: i for i, n in enumerate(EXTENDED_PARAMS)}

deform_st = st.tuples(
    st.floats(-20, 30), *[st.floats(-0.08, 0.08) for _ in range(12)],
    *[st.floats(-0.05, 0.05) for _ in range(4)], *[st.floats(-0.5, 1.0) for _ in range(2)],
    *[st.floats(-0.04, 0.04) for _ in range(2)], st.floats(-30, 30), st.floats(-30, 30),
).map(lambda t: np.r_[t, np.zeros(N - len(t))])


def params(**named) -> np.ndarray:
    p = np.zeros(N)
    for name, value in named.items():
        p[IDX[name]] = value
    return p


def test_layout():
    assert EXTENDED_PARAMS[:13] == PAPER_PARAMS
    assert len(set(EXTENDED_PARAMS)) == N == 29 + len(MOUTH_PARAMS + BASIS_PARAMS + GLOBAL_PARAMS + BODY_PARAMS)
    # appended: older layouts keep their slots
    assert EXTENDED_PARAMS[29:] == MOUTH_PARAMS + BASIS_PARAMS + GLOBAL_PARAMS + BODY_PARAMS
    assert EXTENDED_PARAMS[13:29] == UPPER_PARAMS + ("gaze_yaw", "gaze_pitch", "rx", "ry", "rz", "tx", "ty", "tz")


def test_zero_params_identity():
    assert_allclose(DEF.deform_extended(np.zeros(N)), X, rtol=0, atol=1e-15)


@settings(max_examples=40, deadline=None)
@given(deform_st, st.booleans())
def test_paper_part_unchanged_and_fixed_points_still(p, f3):
    out = DEF.deform_extended(p, f3)
    assert_allclose(out[FIXED_LM], X[FIXED_LM], atol=1e-12)
    p_paper = np.r_[p[:13], np.zeros(N - 13)]
    assert_allclose(DEF.deform_extended(p_paper, f3), DEF.deform(p[:13], f3), atol=1e-15)


def test_upper_face_leaves_lower_face_alone():
    moved = DEF.upper.basis.reshape(len(X), 3, -1).any(axis=(1, 2))
    assert moved.sum() > 100
    assert (DEF.upper.region[moved] >= 0).all() and not DEF.regions.jaw[moved].any()
    assert (DEF.upper.weights.sum(axis=1) <= 1 + 1e-12).all() and (DEF.upper.weights >= 0).all()


def test_new_triangles_do_not_overlap_seen_from_o():
    inside = np.stack([np.nan_to_num(project_weights(X, X[t], DEF.regions.origin), nan=-1).min(axis=1) > 1e-6
                       for t in DEF.upper.triangles])
    assert inside.sum(axis=0).max() <= 1


@settings(max_examples=20, deadline=None)
@given(deform_st)
def test_continuity_across_new_region_borders(p):
    """On the plane through O and an edge shared by two upper regions, both blends agree."""
    vec = np.zeros((len(X), 3))  # the vector of every landmark that is a feature point
    vec[DEF.upper.landmarks] = np.einsum("p,pkd->kd", p[13:21], DEF.upper.vectors)
    o, t = DEF.regions.origin, np.linspace(0.05, 0.95, 7)[:, None]
    tris = [tuple(tr) for tr in DEF.upper.triangles]
    pairs = 0
    for a, b in combinations(tris, 2):
        edge = sorted(set(a) & set(b))
        if len(edge) != 2:
            continue
        pairs += 1
        on_edge = X[edge[0]] + t * (X[edge[1]] - X[edge[0]])
        pts = (o + (on_edge - o) * np.array([0.97, 1.0, 1.03])[:, None, None]).reshape(-1, 3)
        moves = [project_weights(pts, X[list(tr)], o) @ vec[list(tr)] for tr in (a, b)]
        assert_allclose(moves[0], moves[1], atol=1e-12)
    assert pairs >= 60


@pytest.mark.parametrize("side", ["left", "right"])
def test_blink_closes_each_upper_lid_onto_the_lower(side):
    out = DEF.deform_extended(params(**{f"lid_{side[0]}": 1.0}))
    upper = [u for u, _, s in LIDS if s == side]
    lower = [lo for _, lo, s in LIDS if s == side]
    assert len(upper) == 7
    opening = np.linalg.norm(X[upper] - X[lower], axis=1)
    assert opening.max() > 0.02
    assert np.linalg.norm(out[upper] - out[lower], axis=1).max() < 1e-9
    other = [u for u, _, s in LIDS if s != side]
    assert_allclose(out[other], X[other], atol=1e-15)  # the other eye stays open


def test_brows_move_and_knit():
    brow = [p["landmark"] for p in UF.values() if p["role"] == "brow" and p["side"] == "left"]
    up = DEF.deform_extended(params(brow_l_y=0.03))
    assert_allclose(up[brow] - X[brow], np.tile([0, 0.03, 0], (len(brow), 1)), atol=1e-12)
    inner = [UF[n]["landmark"] for n in UF if UF[n]["role"] == "brow" and UF[n]["part"] == "inner"]
    knit = DEF.deform_extended(params(brow_knit=0.02))
    assert (np.abs(knit[inner, 0]) < np.abs(X[inner, 0]) - 0.019).all()


def test_cheek_raise_lifts_cheek_and_lower_lid():
    out = DEF.deform_extended(params(cheek_l=0.03))
    cheek = next(p["landmark"] for p in UF.values() if p["role"] == "cheek" and p["side"] == "left")
    assert out[cheek, 1] - X[cheek, 1] == pytest.approx(0.03)
    lower = [lo for _, lo, s in LIDS if s == "left"]
    assert (out[lower, 1] > X[lower, 1]).all()


@settings(max_examples=30, deadline=None)
@given(st.floats(-40, 40), st.floats(-40, 40), st.floats(-40, 40))
def test_pure_rotation_keeps_distances(rx, ry, rz):
    out = DEF.deform_extended(params(rx=rx, ry=ry, rz=rz))
    sample = X[::7]
    d0 = np.linalg.norm(sample[:, None] - sample[None], axis=2)
    d1 = np.linalg.norm(out[::7][:, None] - out[::7][None], axis=2)
    assert_allclose(d1, d0, atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(deform_st, st.tuples(*[st.floats(-0.5, 0.5)] * 3))
def test_translation_shifts_every_vertex_equally(p, shift):
    moved = p.copy()
    moved[[IDX["tx"], IDX["ty"], IDX["tz"]]] = shift
    assert_allclose(DEF.deform_extended(moved) - DEF.deform_extended(p), np.tile(shift, (len(X), 1)), atol=1e-12)


def test_head_turn_direction():
    out = DEF.deform_extended(params(ry=20.0))
    assert out[1, 0] > X[1, 0] + 0.05  # the nose tip turns toward the face's own left (+x)


@pytest.mark.parametrize("name", UPPER_PARAMS)
def test_linear_at_theta_zero(name):
    """At theta = 0 the displacement is linear in each new parameter."""
    a, b = params(**{name: 0.7}), params(**{name: -0.3})
    disp = lambda p: DEF.deform_extended(p) - X  # noqa: E731
    assert_allclose(disp(a + 2 * b), disp(a) + 2 * disp(b), atol=1e-13)
    assert np.abs(disp(a)).max() > 0


def test_gaze_moves_iris_not_mesh():
    rest = DEF.iris(np.zeros(N))[0]
    p = params(gaze_yaw=20.0, gaze_pitch=10.0)
    assert_allclose(DEF.deform_extended(p), X, atol=1e-15)
    centres, dirs = DEF.iris(p)
    assert (centres[:, 0] > rest[:, 0]).all() and (centres[:, 1] > rest[:, 1]).all()
    assert_allclose(dirs, np.tile(gaze_direction(20.0, 10.0), (2, 1)), atol=1e-12)
    assert_allclose(np.linalg.norm(centres - DEF.eyes.centres, axis=1), DEF.eyes.radius)
    assert_allclose(DEF.eyes.iris_offsets(20.0, 10.0), centres - rest, atol=1e-12)
    turned, _ = DEF.iris(params(ry=90.0))
    assert (turned[:, 0] > rest[:, 0] + 0.05).all()  # the eyes turn with the head


@pytest.mark.parametrize("bad", [np.zeros(13), np.zeros(N + 1), np.r_[np.zeros(N - 1), np.nan]])
def test_bad_params_raise(bad):
    with pytest.raises(ValueError):
        DEF.deform_extended(bad)


# The richer mouth and jaw (codec/model/mouth.py)

def test_mouth_points_move_by_their_vectors_and_paper_points_stay():
    from facedeform.codec.model.mouth import MOUTH_LANDMARKS, UPPER_SIDE
    for point, lm in MOUTH_LANDMARKS.items():
        v = np.array([0.01, 0.02 if point in UPPER_SIDE else -0.02, 0.03])  # lips apart: nothing folds
        p = params(**{f"{point}_{a}": c for a, c in zip("xyz", v)})
        out = DEF.deform_extended(p)
        assert_allclose(out[lm] - X[lm], v, atol=1e-12)
        paper = [FACE.feature_points[n] for n in ("F1", "F2", "F3", "F4", "F8", "F9", "F14", "F15")]
        assert_allclose(out[paper], X[paper], atol=1e-12)


def test_mouth_slit_keeps_the_lips_apart():
    loops = FACE.meta["loops"]
    upper = sorted(set(loops["inner_lip_upper"]) - set(loops["inner_lip_lower"]))
    lower = sorted(set(loops["inner_lip_lower"]) - set(loops["inner_lip_upper"]))
    up = DEF.deform_extended(params(lip_ul_y=0.05, lip_ur_y=0.05, lip_uo_y=0.05)) - X
    down = DEF.deform_extended(params(lip_ll_y=-0.05, lip_lr_y=-0.05, lip_lo_y=-0.05)) - X
    assert_allclose(up[lower], 0.0, atol=1e-12)
    assert_allclose(down[upper], 0.0, atol=1e-12)
    f2, f3 = FACE.feature_points["F2"], FACE.feature_points["F3"]  # paper points: no vector here
    assert (up[[v for v in upper if v != f2], 1] > 0).all() and (down[[v for v in lower if v != f3], 1] < 0).all()


def test_jaw_shift_moves_the_mandible_rigidly_and_leaves_the_upper_face():
    out = DEF.deform_extended(params(jaw_x=0.02, jaw_y=-0.01, jaw_z=0.005)) - X
    assert_allclose(out[DEF.regions.jaw], np.tile([0.02, -0.01, 0.005], (DEF.regions.jaw.sum(), 1)), atol=1e-12)
    assert_allclose(out[FIXED_LM], 0.0, atol=1e-12)


def test_mouth_tiling_blends_agree_on_shared_edges_and_vanish_on_its_rim():
    """Points on an edge shared by two tiles get the same weights from either; rim edges carry paper
    points only, whose vectors are 0 here, so the mouth term is continuous (the slit aside)."""
    from facedeform.codec.model.mouth import MOUTH_LANDMARKS
    tris, o = DEF.mouth.triangles, DEF.regions.origin
    t = np.linspace(0.05, 0.95, 7)[:, None]
    count = {}
    for k, tri in enumerate(tris):
        for e in combinations(sorted(tri), 2):
            count.setdefault(e, []).append(k)
    for (a, b), tiles in count.items():
        if len(tiles) == 1:
            assert not {a, b} & set(MOUTH_LANDMARKS.values())
            continue
        pts = X[a] + t * (X[b] - X[a])
        w = [dict(zip(tris[k], project_weights(pts, X[tris[k]], o).T)) for k in tiles]
        for v in (a, b):
            assert_allclose(w[0][v], w[1][v], atol=1e-9)
