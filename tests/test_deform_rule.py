"""The deformation rules: "paper" is the paper's equations (1) and (2) exactly, checked against an
evaluation written here from the paper's text; "refined" does not fold the lips over."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy.spatial.transform import Rotation

from facedeform.codec.model.deform import KEEP_FACING, PRESETS, Deformer, extended_params
from facedeform.codec.model.face_model import load_base_face
from facedeform.codec.model.folds import Facing, facing_viewer
from facedeform.codec.model.motion_basis import MotionBasis
from facedeform.codec.model.mouth import LOWER_LIP_PARAMS
from facedeform.codec.model.regions import FEATURE_NAMES, RULES
from facedeform.common.errors import InputError
from facedeform.common.parameters import LAYOUTS, MOUTH_PARAMS, PAPER_PARAMS, slots

FACE = load_base_face()
X = FACE.vertices
FP = FACE.feature_points
DEFS = {rule: Deformer(FACE, rule) for rule in RULES}
FIXED = ("F1", "F5", "F6", "F7", "F10", "F11", "F12", "F13")
FREE = ("F2", "F3", "F8", "F9")
#: The range of each vector component fd-send produced on the six dev clips (layouts paper and mouth,
#: smoothing 0 and 1, 4104 frames; 2026-11-24), V3 as its offset from where the jaw carries F3; theta
#: reached 19.2 degrees. Rounded outward. The lower lip went down to 0.194 below the jaw's carry: F3
#: is 0.19 above the chin.
V_LOW = np.array([-0.023, -0.038, -0.022, -0.025, -0.194, -0.055, -0.036, -0.101, -0.072, -0.077, -0.109, -0.087])
V_HIGH = np.array([0.017, 0.077, 0.030, 0.024, 0.037, 0.050, 0.062, 0.056, 0.031, 0.035, 0.055, 0.037])
#: The same for the mouth layout's extra parameters (MOUTH_PARAMS order; 2052 frames).
MOUTH_LOW = np.array([-0.012, -0.009, -0.009, -0.011, -0.007, -0.007, -0.007, -0.049, -0.019, -0.017, -0.050,
                      -0.018, -0.014, -0.012, -0.009, -0.005, -0.026, -0.027, -0.024, -0.036, -0.033])
MOUTH_HIGH = np.array([0.016, 0.045, 0.025, 0.006, 0.047, 0.027, 0.016, 0.012, 0.005, 0.008, 0.010, 0.005, 0.016,
                       0.049, 0.015, 0.003, 0.010, 0.009, 0.016, 0.041, 0.093])


def area(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
    return 0.5 * float(np.linalg.norm(np.cross(b - a, c - a)))


def paper_mesh(points: np.ndarray, params: np.ndarray, f3_with_jaw: bool) -> np.ndarray:
    """Section 3.1 read afresh: rotate F4, F14, F15 (and F3 with the jaw) by theta about the axis
    F12-F13, the chin going down; rotate the jaw band (outside every feature triangle, below the
    plane through O and the axis) rigidly; move every other point by equation (1) over the
    triangle its ray from O crosses, with S1..S3 the unsigned areas around the crossing point,
    equation (2). Points in no triangle above the plane lie beside fixed points only: they stay."""
    pos = {n: X[FP[n]] for n in FP}
    o = np.asarray(FACE.meta["projection_centre_O"], dtype=float)
    axis = (pos["F12"] - pos["F13"]) / np.linalg.norm(pos["F12"] - pos["F13"])
    chin = pos["F4"] - pos["F13"]
    if Rotation.from_rotvec(axis * 0.01).apply(chin)[1] > chin[1]:  # positive angles open the mouth
        axis = -axis
    turn = Rotation.from_rotvec(axis * np.radians(params[0]))
    rotate = lambda p: turn.apply(p - pos["F13"]) + pos["F13"]  # noqa: E731
    v = {n: np.zeros(3) for n in FIXED}
    v.update({n: params[1 + 3 * k: 4 + 3 * k] for k, n in enumerate(FREE)})
    for n in ("F4", "F14", "F15") + (("F3",) if f3_with_jaw else ()):
        v[n] = rotate(pos[n]) - pos[n]
    below = np.cross(pos["F12"] - o, pos["F13"] - o)
    below *= np.sign((pos["F4"] - o) @ below)  # points toward the chin's side
    out = []
    for x in points:
        for names in FACE.meta["stretch_regions"].values():
            a, b, c = (pos[n] for n in names)
            normal = np.cross(b - a, c - a)
            t = ((a - o) @ normal) / ((x - o) @ normal)
            p = o + t * (x - o)
            s = area(p, b, c), area(p, c, a), area(p, a, b)
            if t > 0 and sum(s) <= area(a, b, c) * (1 + 1e-9):
                out.append(x + sum(si * v[n] for si, n in zip(s, names)) / sum(s))
                break
        else:
            out.append(rotate(x) if (x - o) @ below > 0 else x)
    return np.array(out)


def random_params(rng: np.random.Generator, theta_max: float = 30.0) -> np.ndarray:
    return np.r_[rng.uniform(-10, theta_max), rng.uniform(-0.08, 0.08, 12)]


def test_unknown_rule_is_an_input_error():
    assert RULES == ("paper", "refined") and Deformer(FACE).rule == "refined"
    with pytest.raises(InputError, match="paper, refined"):
        Deformer(FACE, "linear")


@pytest.mark.parametrize("f3_with_jaw", [False, True])
def test_paper_rule_is_equation_1_at_random_points(f3_with_jaw):
    """Random points over the lower face and the jaw, appended to the mesh, move as the paper says."""
    rng = np.random.default_rng(7)
    lo, hi = X.min(axis=0), X.max(axis=0)
    points = rng.uniform([lo[0], lo[1], 0.0], [hi[0], 0.1, hi[2]], (300, 3))
    face = dataclasses.replace(FACE, vertices=np.vstack([X, points]))
    deformer = Deformer(face, "paper")
    assert deformer.regions.covered[len(X):].mean() > 0.5 and deformer.regions.jaw[len(X):].sum() > 10
    keep = deformer.regions.covered | deformer.regions.jaw  # off the paper's regions: not its to say
    keep[: len(X)] = False
    for _ in range(3):
        params = random_params(rng)
        assert_allclose(deformer.deform(params, f3_with_jaw)[keep],
                        paper_mesh(face.vertices[keep], params, f3_with_jaw), rtol=0, atol=1e-12)


def test_params_paper_with_the_paper_rule_is_the_paper_on_every_vertex():
    """What the receiver draws for ``--params paper --rule paper`` (head rotation aside)."""
    rng = np.random.default_rng(8)
    names = LAYOUTS["paper"]
    deformer = DEFS["paper"]
    for _ in range(3):
        params = random_params(rng)
        sent = np.r_[params, np.zeros(len(names) - len(PAPER_PARAMS))]
        assert_allclose(deformer.deform_extended(extended_params(names, sent)), paper_mesh(X, params, False),
                        rtol=0, atol=1e-12)
    for preset in ("fig7", "fig8", "fig9"):
        params, f3 = PRESETS[preset]
        assert_allclose(deformer.deform(params, f3), paper_mesh(X, params, f3), rtol=0, atol=1e-12)


def test_the_refined_rule_departs_from_the_paper_only_at_the_mouth_and_the_jaw():
    """The lips (the slit, the rounded lower lip) and what the jaw moves (its lowered pivots): the jaw
    band and the skin that follows F4, F14, F15."""
    params, f3 = PRESETS["fig7"]
    moved = np.linalg.norm(DEFS["refined"].deform(params, f3) - DEFS["paper"].deform(params, f3), axis=1)
    lips = set(FACE.meta["loops"]["inner_lip_upper"]) | set(FACE.meta["loops"]["inner_lip_lower"])
    weights = DEFS["paper"].regions.weights
    lower_lip = weights[:, list(FP).index("F3")] > 0
    jaw = DEFS["paper"].regions.jaw | (weights[:, [list(FP).index(n) for n in ("F4", "F14", "F15")]] > 0).any(axis=1)
    assert moved.max() > 0.01
    assert set(np.flatnonzero(moved > 1e-12)) <= lips | set(np.flatnonzero(lower_lip | jaw))


def flipped(out: np.ndarray) -> np.ndarray:
    """(m,) bool: triangles whose normal turned by more than 90 degrees from the base mesh's, or,
    for those facing the viewer, whose winding on screen (x, y) reversed."""
    f = FACE.faces
    normals = lambda v: np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # noqa: E731
    before, after = normals(X), normals(out)
    facing = before[:, 2] > 0.3 * np.linalg.norm(before, axis=1)
    return (np.sum(before * after, axis=1) <= 0) | (facing & (after[:, 2] * before[:, 2] <= 0))


def jaw_carry(theta: float) -> np.ndarray:
    f3 = X[[FP["F3"]]]
    return DEFS["refined"].rotate_jaw(f3, theta)[0] - f3[0]


@pytest.mark.parametrize("rule", RULES)
def test_an_opening_jaw_folds_no_triangle(rule):
    """Up to 30 degrees, F3 rotated with the jaw or sent where the jaw carries it (the rounding of
    the inner lip, 1 - (1 - w)^2, turned 10 to 18 lower-lip triangles over from 20 degrees)."""
    for theta in np.arange(0.0, 30.01, 0.5):
        params = np.r_[theta, np.zeros(12)]
        assert not flipped(DEFS[rule].deform(params, True)).any(), theta
        params[4:7] = jaw_carry(theta)
        assert not flipped(DEFS[rule].deform(params, False)).any(), theta


def senders_params(rng: np.random.Generator, f3_with_jaw: bool) -> np.ndarray:
    """Extended parameters anywhere in the ranges fd-send produced, the jaw open up to 30 degrees."""
    paper = np.r_[rng.uniform(0, 30), rng.uniform(V_LOW, V_HIGH)]
    if not f3_with_jaw:
        paper[4:7] += jaw_carry(paper[0])
    full = extended_params(PAPER_PARAMS, paper)
    full[slots(MOUTH_PARAMS)] = rng.uniform(MOUTH_LOW, MOUTH_HIGH)
    return full


@pytest.mark.parametrize("f3_with_jaw", [True, False])
def test_the_refined_rule_folds_nothing_over_the_senders_ranges(f3_with_jaw):
    """Vectors anywhere in what fd-send sent on the dev clips, the mouth's extra points too, the jaw
    open up to 30 degrees: nothing folds under the refined rule, though the paper's folds often."""
    rng = np.random.default_rng(9)
    paper_folds = 0
    for _ in range(150):
        params = senders_params(rng, f3_with_jaw)
        assert not flipped(DEFS["refined"].deform_extended(params, f3_with_jaw)).any(), params
        paper_folds += flipped(DEFS["paper"].deform_extended(params, f3_with_jaw)).any()
    assert paper_folds > 30


def test_the_fold_guard_changes_only_what_would_fold():
    """A face that keeps every skin triangle facing its way is drawn as sent; another is drawn with the
    largest part (to the bisection's 2^-12) of its lower lip's motion beyond the jaw's carry that
    keeps them so, when holding the lip at the carry is enough."""
    d = DEFS["refined"]
    rng = np.random.default_rng(10)
    lower_lip = slots(LOWER_LIP_PARAMS)
    guarded = 0
    for _ in range(60):
        params = senders_params(rng, False)
        drawn = d.unfold(params)
        assert_allclose(d.deform_extended(params), d.blend(drawn), rtol=0, atol=1e-15)  # the pose, zero, rounds
        if not d.would_fold(params):
            assert_array_equal(drawn, params)
            continue
        assert not d.would_fold(drawn)
        held = params.copy()
        held[4:7], held[lower_lip] = jaw_carry(params[0]), 0.0
        if d.would_fold(held):
            continue
        guarded += 1
        s = (drawn - held)[4] / (params - held)[4]
        assert 0 <= s < 1
        assert_allclose(drawn, held + s * (params - held), rtol=0, atol=1e-15)
        assert d.would_fold(held + (s + 2.0 ** -11) * (params - held))
    assert 3 <= guarded <= 57


def test_an_edge_on_sliver_turned_over_does_not_scale_the_mouth_back():
    """The sliver in the mouth's right corner (inner corner 308, edge-on at rest) turned over by a speaker's
    pattern that moves the corner alone: drawn as sent with the jaw open, where guarding every triangle
    drew the whole mouth scaled back; the same pattern pushed on until a triangle facing the viewer
    turns over is still scaled back."""
    sliver = np.flatnonzero((np.sort(FACE.faces, axis=1) == [292, 308, 415]).all(axis=1))
    assert len(sliver) == 1 and not facing_viewer(X, FACE.faces[sliver])[0]
    a, b = X[292], X[415]
    foot = a + (X[308] - a) @ (b - a) / ((b - a) @ (b - a)) * (b - a)
    pattern = (foot - X[308])[None, None] / np.linalg.norm(foot - X[308])  # the corner across the sliver's edge
    face = dataclasses.replace(FACE, motion=MotionBasis(np.array([308]), pattern))
    d = Deformer(face, "refined")
    names = ("theta", "basis_0")
    skin = ~(d.upper.region >= 0)[FACE.faces].any(axis=1)  # below the upper face, which guards its own blinks
    shown = skin & facing_viewer(X, FACE.faces)
    every, guarded = (Facing(X, FACE.faces[m], (FACE.mouth_faces | FACE.eye_faces)[m]) for m in (skin, shown))
    mesh = lambda c: d.blend(extended_params(names, [15.0, c]))  # noqa: E731
    moved = next(c for c in np.arange(0.0005, 0.05, 0.0005) if every.kept(mesh(c))[skin[:sliver[0]].sum()] < -0.5)
    assert every.folded(mesh(moved), KEEP_FACING).any() and not guarded.folded(mesh(moved), KEEP_FACING).any()
    params = extended_params(names, [15.0, moved])
    assert not d.would_fold(params)
    assert_array_equal(d.unfold(params), params)
    far = next(c for c in np.arange(moved, 0.5, 0.0005) if guarded.folded(mesh(c), KEEP_FACING).any())
    assert d.would_fold(extended_params(names, [15.0, far]))
    assert d.unfold(extended_params(names, [15.0, far]))[slots(("basis_0",))][0] < far


def test_a_speakers_closed_mouth_opens_without_folding(face):
    """A speaker's mesh (the sample's, fitted to a closed mouth) takes each vertex's region from the
    shipped mesh (codec/model/regions): by its own geometry its lower lip's outer vertices by the
    corners fell in the upper lip's regions, and the lower lip sent 0.01 down folded the triangles
    between them and the inner lip (the fold guard then held the lips 0.013 apart)."""
    deformer = Deformer(face.model, "refined")
    by_corners = [319, 325, 403, 89, 96, 179]
    f1, f2 = (FEATURE_NAMES.index(n) for n in ("F1", "F2"))
    assert not deformer.regions.weights[by_corners][:, [f1, f2]].any()
    rest = face.model.vertices
    for down in (0.02, 0.04, 0.06):
        p = np.zeros(len(PAPER_PARAMS))
        p[PAPER_PARAMS.index("v3y")] = -down
        p = extended_params(PAPER_PARAMS, p)
        assert not deformer.would_fold(p)
        out = deformer.deform_extended(p)
        assert out[13, 1] - out[14, 1] == pytest.approx(rest[13, 1] - rest[14, 1] + down, abs=1e-3)
