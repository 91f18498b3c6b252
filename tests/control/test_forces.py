"""Grasp matrix and contact-force distribution: statics identities and posture feasibility."""

from __future__ import annotations

import numpy as np
import pytest

from inhand_exp.config import HandConfig, ObjectConfig, PrimitivesConfig, SimConfig
from inhand_exp.control.forces import Squeeze, solve_lp
from inhand_exp.control.grasp import Contacts, Face, Posture, contact_frames, grasp_matrix
from inhand_exp.control.hand import HandModel

L, R = Face.LEFT, Face.RIGHT  # the pole's long sides
G_ACC = SimConfig().gravity_mps2
OBJ = ObjectConfig()
GAINS = PrimitivesConfig()
MODEL = HandModel.from_config(HandConfig(), OBJ, G_ACC)
MU = MODEL.mu * GAINS.friction_margin
F_MIN, F_MAX = GAINS.min_normal_force_n, GAINS.max_normal_force_n
GRAVITY_WRENCH = np.array([0.0, OBJ.mass_kg * G_ACC, 0.0])  # what the contacts must supply
# a three-point bend of the upright pole: finger 1 alone on the right, between the others
BEND = Contacts(Posture((L, R, L)), (-0.12, 0.0, 0.12))


def _g(contacts: Contacts, theta: float = 0.0) -> np.ndarray:
    """G in the object frame (COM at the origin) for the active contacts."""
    pts, nrm = contact_frames(MODEL.shape, contacts, np.array([0.0, 0.0, theta]))
    keep = list(contacts.active)
    return grasp_matrix(pts[keep], nrm[keep])


def _check_lam(G: np.ndarray, lam: np.ndarray, w: np.ndarray, f_max: float = F_MAX,
               f_min: float = F_MIN) -> None:
    fn, ft = lam[0::2], lam[1::2]
    np.testing.assert_allclose(G @ lam, w, rtol=0, atol=1e-9)
    assert np.all(fn >= f_min - 1e-9), fn
    assert np.all(fn <= f_max + 1e-9), fn
    assert np.all(np.abs(ft) <= MU * fn + 1e-9), (ft, fn)


def test_grasp_matrix_is_sum_of_forces_and_torques():
    rng = np.random.default_rng(0)
    for k in (1, 2, 3, 4):
        for _ in range(20):
            levers = rng.uniform(-0.3, 0.3, (k, 2))
            ang = rng.uniform(-np.pi, np.pi, k)
            normals = np.column_stack([np.cos(ang), np.sin(ang)])
            lam = rng.uniform(-5.0, 5.0, 2 * k)
            force, torque = np.zeros(3), 0.0
            for i in range(k):
                # in 3D (x, y, z); the tangent is the normal turned +90 deg about -y
                n3 = np.array([normals[i, 0], 0.0, normals[i, 1]])
                t3 = np.cross([0.0, -1.0, 0.0], n3)
                f3 = lam[2 * i] * n3 + lam[2 * i + 1] * t3
                r3 = np.array([levers[i, 0], 0.0, levers[i, 1]])
                force += f3
                torque += -np.cross(r3, f3)[1]  # component about -y: counter-clockwise
            np.testing.assert_allclose(grasp_matrix(levers, normals) @ lam,
                                       [force[0], force[2], torque], rtol=0, atol=1e-12)


def test_grasp_matrix_tangent_is_ccw_of_normal():
    G = grasp_matrix(np.array([[0.0, 0.0]]), np.array([[1.0, 0.0]]))
    np.testing.assert_array_equal(G[:2, 1], [0.0, 1.0])


def _random_wrenches(n: int, seed: int, f_scale: float = 3.0, t_scale: float = 0.2):
    rng = np.random.default_rng(seed)
    return [np.array([*rng.uniform(-f_scale, f_scale, 2), rng.uniform(-t_scale, t_scale)])
            for _ in range(n)]


@pytest.mark.parametrize("theta", [0.0, 0.4, -1.2])
def test_bend_grasp_random_wrenches(theta):
    """Both solvers balance the wrench inside the cones; squeeze never claims more than the LP."""
    G = _g(BEND, theta)
    sq = Squeeze.build(G, MU, F_MIN, F_MAX)
    assert sq.usable
    feasible = 0
    for w in _random_wrenches(100, 1):
        lam_lp = solve_lp(G, w, MU, F_MIN, F_MAX)
        lam_sq = sq.solve(w)
        if lam_lp is not None:
            _check_lam(G, lam_lp, w)
            feasible += 1
        if lam_sq is not None:
            _check_lam(G, lam_sq, w)
            assert lam_lp is not None  # squeeze is never less conservative than the LP
            # the LP minimises the total normal force
            assert lam_lp[0::2].sum() <= lam_sq[0::2].sum() + 1e-7
        if lam_lp is None:
            assert lam_sq is None
    assert feasible >= 90


def test_bend_grasp_large_wrenches_agree_on_infeasibility():
    """Wrenches up to 60 N: some exceed f_max; whenever the LP says no, squeeze says no too."""
    G = _g(BEND)
    sq = Squeeze.build(G, MU, F_MIN, F_MAX)
    outcomes = set()
    for w in _random_wrenches(200, 2, f_scale=60.0, t_scale=3.0):
        lam_lp, lam_sq = solve_lp(G, w, MU, F_MIN, F_MAX), sq.solve(w)
        outcomes.add((lam_lp is None, lam_sq is None))
        if lam_lp is None:
            assert lam_sq is None
        else:
            _check_lam(G, lam_lp, w)
        if lam_sq is not None:
            _check_lam(G, lam_sq, w)
    assert (True, True) in outcomes and (False, False) in outcomes


def _both(contacts: Contacts, w: np.ndarray = GRAVITY_WRENCH, f_min: float = F_MIN,
          theta: float = 0.0):
    G = _g(contacts, theta)
    return G, solve_lp(G, w, MU, f_min, F_MAX), Squeeze.build(G, MU, f_min, F_MAX).solve(w)


def test_three_point_bend_holds_gravity():
    G, lam_lp, lam_sq = _both(BEND)
    assert lam_lp is not None and lam_sq is not None
    _check_lam(G, lam_lp, GRAVITY_WRENCH)
    _check_lam(G, lam_sq, GRAVITY_WRENCH)


@pytest.mark.parametrize("coords", [(-0.12, 0.0, 0.12), (-0.2, -0.1, 0.2), (-0.12, 0.11, 0.12)])
def test_lone_finger_between_pair_has_squeeze(coords):
    _, lam_lp, lam_sq = _both(Contacts(Posture((L, R, L)), coords))
    assert lam_lp is not None and lam_sq is not None


@pytest.mark.parametrize("faces, coords", [
    ((L, L, R), (-0.12, 0.0, 0.12)),
    ((R, L, L), (-0.12, 0.0, 0.12)),
    ((R, R, L), (-0.12, 0.0, 0.12)),
])
def test_lone_finger_outside_pair_is_infeasible(faces, coords):
    G, lam_lp, lam_sq = _both(Contacts(Posture(faces), coords))
    assert lam_lp is None
    assert lam_sq is None
    assert not Squeeze.build(G, MU, F_MIN, F_MAX).usable


def test_all_fingers_on_one_side_is_infeasible():
    _, lam_lp, lam_sq = _both(Contacts(Posture((R, R, R)), (-0.12, 0.0, 0.12)))
    assert lam_lp is None and lam_sq is None


def test_all_fingers_below_only_rests():
    """Three fingers under the upright pole's lower end can only support it: no internal
    squeeze exists, and balancing gravity needs 3 f_min <= m g."""
    contacts = Contacts(Posture((Face.BOTTOM,) * 3), (-0.008, 0.0, 0.008))
    G, lam_lp, lam_sq = _both(contacts)
    assert GRAVITY_WRENCH[1] < 3 * F_MIN
    assert lam_lp is None and lam_sq is None
    assert not Squeeze.build(G, MU, F_MIN, F_MAX).usable
    f_min = GRAVITY_WRENCH[1] / 4
    G, lam_lp, lam_sq = _both(contacts, f_min=f_min)
    assert lam_lp is not None
    _check_lam(G, lam_lp, GRAVITY_WRENCH, f_min=f_min)
    if lam_sq is not None:  # squeeze may refuse a grasp without internal force, or solve it
        _check_lam(G, lam_sq, GRAVITY_WRENCH, f_min=f_min)
    # fingers that can only push up cannot pull the object down
    G, lam_lp, _ = _both(contacts, w=-GRAVITY_WRENCH, f_min=0.0)
    assert lam_lp is None


@pytest.mark.parametrize("coord", [0.0, 0.01, -0.02])
def test_pinch_near_com_is_feasible(coord):
    contacts = Contacts(Posture((L, R, L)), (0.0, coord, 0.0), active=(False, True, True))
    contacts = contacts.moved(2, coord=coord)
    G, lam_lp, lam_sq = _both(contacts)
    assert G.shape == (3, 4)
    assert lam_lp is not None and lam_sq is not None
    _check_lam(G, lam_lp, GRAVITY_WRENCH)
    _check_lam(G, lam_sq, GRAVITY_WRENCH)


def test_pinch_far_from_com_needs_large_squeeze():
    """Tilted to horizontal (theta = pi/2), the gravity torque of a pinch 0.2 m from the COM is
    carried by the friction couple across the 2 cm width: feasible, but only with normal forces
    far above the near pinch's. Upright, gravity runs along the pole and has no lever: the far
    pinch costs no more than the near one."""
    near = Contacts(Posture((L, R, L)), (0.0, 0.0, 0.0), active=(False, True, True))
    far = Contacts(Posture((L, R, L)), (0.0, 0.2, 0.2), active=(False, True, True))
    flat = np.pi / 2
    _, near_lp, _ = _both(near, theta=flat)
    G, far_lp, far_sq = _both(far, theta=flat)
    assert near_lp is not None and far_lp is not None and far_sq is not None
    _check_lam(G, far_sq, GRAVITY_WRENCH)
    assert far_lp[0::2].sum() > 10 * near_lp[0::2].sum()
    assert solve_lp(G, GRAVITY_WRENCH, MU, F_MIN, f_max=5.0) is None
    assert Squeeze.build(G, MU, F_MIN, 5.0).solve(GRAVITY_WRENCH) is None
    _, near_up, _ = _both(near)
    G, far_up, _ = _both(far)
    assert near_up is not None and far_up is not None
    _check_lam(G, far_up, GRAVITY_WRENCH)
    assert far_up[0::2].sum() == pytest.approx(near_up[0::2].sum(), rel=1e-6)
    assert solve_lp(G, GRAVITY_WRENCH, MU, F_MIN, f_max=5.0) is not None


@pytest.mark.parametrize("w", [np.array([0.0, 200.0, 0.0]), np.array([150.0, 0.0, 0.0]),
                               np.array([0.0, -200.0, 0.0])])
def test_wrench_beyond_f_max_is_infeasible(w):
    G = _g(BEND)
    assert solve_lp(G, w, MU, F_MIN, F_MAX) is None
    assert Squeeze.build(G, MU, F_MIN, F_MAX).solve(w) is None
    # the same wrench is fine without the upper bound
    lam = solve_lp(G, w, MU, F_MIN)
    assert lam is not None
    assert lam[0::2].max() > F_MAX
    lam = Squeeze.build(G, MU, F_MIN).solve(w)
    assert lam is not None
    _check_lam(G, lam, w, f_max=np.inf)


@pytest.mark.parametrize("firm", [False, True])
@pytest.mark.parametrize("seed", range(6))
def test_landing_span_bounds_every_strict_hold(seed, firm):
    """Wherever a finger moved to the other face admits a strict squeeze (``firm``: with at
    least ``min_grasp_margin`` of slack), its coordinate lies inside ``landing_span``; just
    outside the span none does, and well inside it every one does."""
    from inhand_exp.control.flip import OPPOSITE
    from inhand_exp.control.repose import landing_span, strict_hold
    from inhand_exp.control.sample import random_grasp

    model = HandModel.from_config(HandConfig(), ObjectConfig(), SimConfig().gravity_mps2)
    gains = PrimitivesConfig()
    rng = np.random.default_rng(seed)
    _, contacts, _ = random_grasp(model, rng)
    grid = np.linspace(-0.24, 0.24, 97)

    def holds(finger, face, c):
        return strict_hold(model, contacts.moved(finger, coord=float(c), face=face), gains,
                           firm=firm)

    spans = 0
    for finger in range(3):
        face = OPPOSITE[contacts.posture.faces[finger]]
        span = landing_span(model, contacts, finger, face, gains, firm=firm)
        held = [c for c in grid if holds(finger, face, c)]
        if span is None:
            assert held == []
            continue
        spans += 1
        lo, hi = span
        assert all(lo - 1e-6 <= c <= hi + 1e-6 for c in held), (finger, span, held)
        assert all(c in held for c in grid if lo + 1e-5 <= c <= hi - 1e-5), (finger, span)
        for c in (lo - 1e-3, hi + 1e-3):
            if abs(c) < 0.25:
                assert not holds(finger, face, c)
        if hi - lo > 0.02:  # well inside a wide span the grasp holds
            assert holds(finger, face, (lo + hi) / 2)
    assert spans >= 1


def _slide_lp(contacts: Contacts, sliding: int, drag: float, theta: float = 0.0):
    """The per-step LP of a slide plan (``light``: the sliding finger presses lightly)."""
    G = _g(contacts, theta)
    return G, Squeeze.build(G, MU, F_MIN, F_MAX, {sliding: drag}, light=(sliding,))


@pytest.mark.parametrize(("sliding", "drag", "theta"), [(0, MU, 0.0), (1, -MU, 0.3),
                                                        (2, 0.0, -0.8), (1, 0.0, 1.2)])
def test_vertex_solver_finds_the_lp_optimum_of_slide_plans(sliding, drag, theta):
    """The per-step LP of a slide, solved by vertex enumeration: feasible exactly when HiGHS
    finds it feasible, at the same optimal cost, inside the cones; where the optimum is a
    face, the mean of its vertices (strictly inside when the face is an edge)."""
    from inhand_exp.control.lp import SmallLP, VertexLP

    G, sq = _slide_lp(BEND, sliding, drag, theta)
    sq.solve(GRAVITY_WRENCH)
    assert isinstance(sq.lp, VertexLP)
    m = len(sq.cols)
    rows = [r for a, b in sq.fric for r in (np.eye(m)[b] - MU * np.eye(m)[a],
                                             -np.eye(m)[b] - MU * np.eye(m)[a])]
    lower, upper = np.full(m, -np.inf), np.full(m, np.inf)
    lower[sq.fn], upper[sq.fn] = F_MIN, F_MAX
    highs = SmallLP(sq.cost, sq.G, np.array(rows), np.zeros(len(rows)), lower, upper)
    agree = 0
    for w in _random_wrenches(150, 3, f_scale=8.0, t_scale=0.4):
        ref, got = highs.solve(w), sq.solve(w)
        assert (ref is None) == (got is None)
        if got is None:
            continue
        agree += 1
        _check_lam(G, got, w)
        red = got[sq.cols]
        assert sq.cost @ red == pytest.approx(sq.cost @ ref, abs=1e-8)
    assert agree >= 50


def test_vertex_solver_returns_the_middle_of_an_optimal_edge():
    """min f1 + f2 with f1 + f2 = 2, 0 <= f1 <= 2: every point is optimal; the middle is
    returned, not an end where a bound is tight."""
    from inhand_exp.control.lp import VertexLP

    lp = VertexLP(np.array([1.0, 1.0, 0.0]), np.array([[1.0, 1.0, 0.0], [0.0, 0.0, 1.0]]), None,
                  None, np.array([0.0, 0.0, -np.inf]), np.array([2.0, 2.0, np.inf]))
    assert lp.ok
    np.testing.assert_allclose(lp.solve(np.array([2.0, 0.5])), [1.0, 1.0, 0.5], atol=1e-12)
    assert lp.solve(np.array([5.0, 0.0])) is None  # f1 + f2 = 5 exceeds the bounds
    assert not VertexLP.fits(np.ones((1, 5)))  # four dimensions left: HiGHS does those


def test_pooled_solvers_answer_as_new_ones():
    """A HiGHS instance handed on from an LP that is gone starts with no basis."""
    import gc

    from inhand_exp.control.lp import _POOL, SmallLP

    rng = np.random.default_rng(4)
    problems = [(rng.uniform(0.5, 1.5, 6), rng.normal(size=(3, 6)), rng.normal(size=(4, 6)))
                for _ in range(5)]
    b = np.full(3, 0.3)
    fresh = []
    for c, A_eq, A_ub in problems:
        lp = SmallLP(c, A_eq, A_ub, np.full(4, 5.0), np.zeros(6), np.full(6, 10.0))
        fresh.append((lp.solve(b), lp.h.getInfo().simplex_iteration_count))
        del lp
        gc.collect()
        assert _POOL  # its solver went back to the pool
    for (c, A_eq, A_ub), (x, iterations) in zip(problems, fresh, strict=True):
        lp = SmallLP(c, A_eq, A_ub, np.full(4, 5.0), np.zeros(6), np.full(6, 10.0))
        y = lp.solve(b)
        assert (x is None) == (y is None) and lp.h.getInfo().simplex_iteration_count == iterations
        if x is not None:
            np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("seed", [0, 1])
def test_pointed_one_off_lps_match_highs(seed, monkeypatch):
    """The one-off LPs (least squeeze, deepest squeeze, strict span) solved by vertex
    enumeration give HiGHS's optimal cost and the same feasibility verdicts."""
    from inhand_exp.control import forces, lp
    from inhand_exp.control.repose import landing_span, strict_hold

    rng = np.random.default_rng(seed)
    cases = []
    for _ in range(40):
        faces = tuple(rng.choice([L, R], 3))
        contacts = Contacts(Posture(faces), tuple(rng.uniform(-0.2, 0.2, 3)))
        G = _g(contacts, float(rng.uniform(-1.2, 1.2)))
        w = np.array([rng.normal(0, 1.0), rng.uniform(0.5, 3.0), rng.normal(0, 0.05)])
        cases.append((contacts, G, w))

    def answers():
        out = []
        for contacts, G, w in cases:
            lam = solve_lp(G, w, MU, F_MIN, F_MAX)
            k = G.shape[1] // 2
            lam0, margin = forces._deepest_squeeze(G, np.arange(0, 2 * k, 2),
                                                   np.arange(2 * k).reshape(-1, 2), MU)
            span = landing_span(MODEL, contacts, 1, contacts.posture.faces[1], GAINS)
            out.append((None if lam is None else lam[0::2].sum(), margin,
                        strict_hold(MODEL, contacts, GAINS), span))
        return out

    vertex = answers()
    monkeypatch.setattr(lp.VertexLP, "fits", classmethod(lambda cls, A: False))  # HiGHS only
    highs = answers()
    for (cost_v, margin_v, hold_v, span_v), (cost_h, margin_h, hold_h, span_h) in zip(
            vertex, highs, strict=True):
        assert (cost_v is None) == (cost_h is None)
        if cost_v is not None:
            assert cost_v == pytest.approx(cost_h, abs=1e-7)
        assert margin_v == pytest.approx(margin_h, abs=1e-7) and hold_v == hold_h
        assert (span_v is None) == (span_h is None)
        if span_v is not None:
            np.testing.assert_allclose(span_v, span_h, atol=1e-7)
    assert any(h[2] for h in highs) and not all(h[2] for h in highs)  # both verdicts seen
