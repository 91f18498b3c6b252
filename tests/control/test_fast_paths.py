"""The hot paths written for speed give what the plain vector forms give.

The slide's torque law runs in plain floats; here it is checked, step by step of real slides,
against the same law written with numpy vectors (the form it had before), to 1e-9 N m. The
vertex enumeration's shared cross products are checked bit for bit against one product per
choice.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from inhand_exp.config import PrimitivesConfig
from inhand_exp.control.execute import execute
from inhand_exp.control.grasp import Contacts, Face, Posture, rotation
from inhand_exp.control.lp import VertexLP, _cross
from inhand_exp.control.repose import (
    contact_force,
    damped_qdd,
    follow_qdd,
    min_jerk,
    object_wrench,
    push_torque,
)
from inhand_exp.control.slide import Slide

L, R = Face.LEFT, Face.RIGHT
X0 = np.array([0.0, 0.34, 0.0])
BEND = Contacts(Posture((L, L, R)), (-0.21, -0.09, -0.15))


def vector_slide_qdd(s: Slide, obs, R: np.ndarray, acc: np.ndarray) -> np.ndarray:
    """The sliding finger's joint accelerations, in numpy vectors."""
    model, i = s.model, s.finger
    finger = model.fingers[i]
    c, cd, cdd = min_jerk(np.array([s.c0]), np.array([s.c1]), s.move_s, obs.t)
    along_W = R @ s.along_O
    surface_O, _ = model.shape.local_contact(s.contacts.posture.faces[i], float(c[0]))
    target_W = obs.pose[:2] + R @ (surface_O - model.tip_radius * s.n_O)
    qi, qdi = obs.q[2 * i:2 * i + 2], obs.qd[2 * i:2 * i + 2]
    t = finger.terms(qi[0], qi[1], qdi[0], qdi[1])
    tip = np.array([t.x, t.z])
    v_tip = np.array([t.j11 * qdi[0] + t.j12 * qdi[1], t.j21 * qdi[0] + t.j22 * qdi[1]])
    r = tip - obs.pose[:2]
    omega = obs.twist[2]
    v_obj = obs.twist[:2] + omega * np.array([-r[1], r[0]])
    a_obj = acc[:2] + acc[2] * np.array([-r[1], r[0]]) - omega**2 * r
    e_t = float(along_W @ (target_W - tip))
    ed_t = float(cd[0]) - float(along_W @ (v_tip - v_obj))
    a_tip = a_obj + along_W * (float(cdd[0]) + s.kp * e_t + s.kd * ed_t)
    return np.array(damped_qdd(t, a_tip[0], a_tip[1]))


def vector_slide_torques(s: Slide, obs) -> np.ndarray | None:
    """``Slide.torques`` in numpy vectors (the plans as ``Slide.torques`` leaves them)."""
    model, i = s.model, s.finger
    s._mark_stale(obs)
    plan = s._planned("plan" if obs.t < s.move_s else "rest", obs)
    zero = np.zeros(3)
    acc, w_O = object_wrench(model, s.gains, obs.pose, obs.twist, (s.origin, zero, zero))
    lam, sliding = plan.squeeze.solve(w_O), True
    if lam is None:
        plan, sliding = s._planned("hold", obs), False
        lam = plan.squeeze.solve(w_O)
    if lam is None:
        return None
    R = rotation(obs.pose[2])
    tau = np.zeros(6)
    for k, j in enumerate(plan.fingers):
        f_W, n_W = contact_force(plan, lam, k, R), R @ plan.normals_O[k]
        if j == i and sliding:
            qdd = vector_slide_qdd(s, obs, R, acc)
        else:
            qdd = follow_qdd(model, j, obs.q, obs.qd, plan.tips_O[k], acc, obs.twist[2], R)
        tau[2 * j:2 * j + 2] = push_torque(model, j, obs.q, obs.qd, qdd, f_W, n_W)
    return tau


class Compared:
    """A slide whose every torque is also computed in vector form, the difference kept."""

    def __init__(self, slide: Slide):
        self.slide, self.duration_s = slide, slide.duration_s
        self.gaps: list[float] = []

    def start(self, obs) -> str | None:
        return self.slide.start(obs)

    def torques(self, obs) -> np.ndarray | None:
        expected = vector_slide_torques(self.slide, obs)
        tau = self.slide.torques(obs)
        assert (tau is None) == (expected is None)
        if tau is not None:
            self.gaps.append(float(np.abs(tau - expected).max()))
        return tau

    def achieved(self, obs) -> str | None:
        return self.slide.achieved(obs)


@pytest.mark.parametrize(("finger", "dc"), [(0, 0.02), (1, -0.02), (2, 0.02)],
                         ids=["0+", "1-", "2+"])
def test_the_slides_float_torques_equal_the_vector_form(nominal_model, make_world, finger, dc):
    world = make_world(BEND, X0)
    slide = Compared(Slide(nominal_model, BEND, finger, dc, 0.5,
                           PrimitivesConfig(end_margin_m=0.0)))
    out = execute(world, slide)
    assert out.reason == "done", out
    assert len(slide.gaps) == out.steps  # every step compared, the whole slide long
    assert max(slide.gaps) < 1e-9, max(slide.gaps)


def test_shared_cross_products_are_each_choices_own_bit_for_bit():
    rng = np.random.default_rng(0)
    for p in (3, 4, 7, 10, 13):
        rows = rng.normal(size=(p, 3))
        combos = np.array(list(itertools.combinations(range(p), 3)), dtype=np.intp)
        X = rows[combos]
        r0, r1, r2 = (np.ascontiguousarray(X[:, t]) for t in range(3))
        own = np.stack([_cross(r1, r2), _cross(r2, r0), _cross(r0, r1)], axis=1)
        np.testing.assert_array_equal(VertexLP._cofactors3(rows, combos), own)
        # the cofactors invert: each choice's rows times its cofactors is det * I
        det = np.einsum("ij,ij->i", r0, own[:, 0])
        keep = np.abs(det) > 1e-6
        np.testing.assert_allclose(np.einsum("kij,klj->kil", X, own)[keep],
                                   det[keep, None, None] * np.eye(3), atol=1e-9)
