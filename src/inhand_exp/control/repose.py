"""Repose (paper eq. 4-5): move the object by contact forces while every contact stays put.

Per physics step: a PD on the object pose around a minimum-jerk reference gives the desired
object acceleration; the object's nominal dynamics give the wrench the contacts must apply; the
force distribution (``forces.Squeeze``) splits it into contact forces inside the friction cones;
each finger then gets inverse-dynamics torques that move its tip like the object-fixed contact
point, plus ``J_c^T f`` to push with its share of the force. Hold is a repose to the current pose.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from inhand_exp.config import PrimitivesConfig
from inhand_exp.control.finger import FingerTerms
from inhand_exp.control.forces import Squeeze, has_strict_squeeze, squeeze_margin, strict_span
from inhand_exp.control.grasp import (
    Contacts,
    Face,
    contact_frames,
    cross2,
    face_axes,
    face_shifted,
    grasp_matrix,
    rotation,
)
from inhand_exp.control.hand import HandModel, elongated


@dataclass(frozen=True)
class GraspPlan:
    """A contact configuration frozen in the object frame, with its force distribution.

    Built once per primitive from the measured fingertips and the observed object pose.
    """

    fingers: tuple[int, ...]  # fingers in contact, in order of the columns of G
    levers_O: np.ndarray  # (k, 2) contact points from the COM, object frame (m)
    normals_O: np.ndarray  # (k, 2) inward normals, object frame
    tips_O: np.ndarray  # (k, 2) fingertip centres from the COM, object frame (m)
    squeeze: Squeeze

    @functools.cached_property
    def floats(self) -> tuple[tuple[int, float, float, float, float], ...]:
        """Per contact ``(finger, tip_x, tip_z, normal_x, normal_z)`` in O, as plain floats."""
        return tuple((i, *map(float, t), *map(float, n))
                     for i, t, n in zip(self.fingers, self.tips_O, self.normals_O, strict=True))

    @classmethod
    def from_state(cls, model: HandModel, contacts, pose: np.ndarray, q: np.ndarray,
                   gains: PrimitivesConfig, sliding: int | None = None, drag: float = 0.0
                   ) -> GraspPlan:
        """Plan for ``contacts`` (which fingers and faces) at the fingertips' measured places.

        Each active tip is projected onto its face: the contact coordinate comes from the
        joints (measured) and the object pose (observed), not from a commanded target. The
        ``sliding`` finger gets a normal force plus ``drag`` times it along the contact
        tangent (kinetic friction; zero for a frictionless push).
        """
        return cls._planned(model, *measured_geometry(model, contacts, pose, q), gains,
                            sliding, drag)

    @classmethod
    def from_contacts(cls, model: HandModel, contacts, gains: PrimitivesConfig,
                      sliding: int | None = None, drag: float = 0.0) -> GraspPlan:
        """The same plan for the commanded contacts (each tip exactly at its coordinate), in
        the object frame: what a planner without joints can ask of a cell."""
        pts_O, nrm_O = contact_frames(model.shape, contacts, np.zeros(3))
        fingers = tuple(i for i in range(3) if contacts.active[i])
        levers_O, normals_O = pts_O[list(fingers)], nrm_O[list(fingers)]
        return cls._planned(model, fingers, levers_O, normals_O,
                            levers_O - model.tip_radius * normals_O,
                            grasp_matrix(levers_O, normals_O), gains, sliding, drag)

    @classmethod
    def _planned(cls, model: HandModel, fingers: tuple[int, ...], levers_O: np.ndarray,
                 normals_O: np.ndarray, tips_O: np.ndarray, G: np.ndarray,
                 gains: PrimitivesConfig, sliding: int | None, drag: float) -> GraspPlan:
        coupled = {k: drag for k, i in enumerate(fingers) if i == sliding}
        sq = Squeeze.build(G, model.mu * gains.friction_margin, gains.min_normal_force_n,
                           gains.max_normal_force_n, coupled, light=tuple(coupled))
        return cls(fingers, levers_O, normals_O, tips_O, sq)


def measured_geometry(model: HandModel, contacts, pose: np.ndarray, q: np.ndarray) -> tuple:
    """``(fingers, levers_O, normals_O, tips_O, G)`` of ``contacts`` at the measured tips (see
    ``GraspPlan.from_state``): what the plans of one state share, whichever finger slides."""
    R = rotation(pose[2])
    tips_W = model.tips(q)
    _, nrm_W = contact_frames(model.shape, contacts, pose)
    fingers = tuple(i for i in range(3) if contacts.active[i])
    tips_O = np.array([R.T @ (tips_W[i] - pose[:2]) for i in fingers])
    normals_O = np.array([R.T @ nrm_W[i] for i in fingers])
    levers_O = tips_O + model.tip_radius * normals_O
    return fingers, levers_O, normals_O, tips_O, grasp_matrix(levers_O, normals_O)


def plan_for(model: HandModel, contacts, obs, gains: PrimitivesConfig, sliding: int | None = None,
             drag: float = 0.0) -> GraspPlan:
    """``GraspPlan.from_state`` on ``obs``, built once per observation when it carries a cache
    (and the geometry shared by the plans of the same contacts, whichever finger slides).

    Plans are immutable apart from the warm start of their per-step LP, which changes how fast
    a solve is, not its answer.
    """
    if obs.plans is None:
        return GraspPlan.from_state(model, contacts, obs.pose, obs.q, gains, sliding, drag)
    key = (id(model), contacts, id(gains), sliding, drag)
    plan = obs.plans.get(key)
    if plan is None:
        where = ("geometry", id(model), contacts)
        geometry = obs.plans.get(where)
        if geometry is None:
            geometry = obs.plans[where] = measured_geometry(model, contacts, obs.pose, obs.q)
        plan = GraspPlan._planned(model, *geometry, gains, sliding, drag)
        obs.plans[key] = plan
    return plan


def face_gaps(model: HandModel, contacts, obs) -> tuple[float, ...]:
    """Each finger's tip gap to its nominal face in ``obs`` (``HandModel.surface_gap``: where
    it finds its face), worked out once per observation when it carries a cache."""
    key = ("gaps", id(model), contacts)
    if obs.plans is not None and key in obs.plans:
        return obs.plans[key]
    gaps = tuple(model.surface_gap(i, face, obs.pose, obs.q)[0]
                 for i, face in enumerate(contacts.posture.faces))
    if obs.plans is not None:
        obs.plans[key] = gaps
    return gaps


def face_gap(model: HandModel, contacts: Contacts, face: Face, obs,
             exclude: int | None = None) -> float:
    """Where ``face`` is found, off the nominal one (m, outward positive): the mean gap of the
    fingertips that touch it (0 if none does). A thinner object, or an error in the observed
    pose, shows here as the fingers' own positions."""
    gaps = [g for j, g in enumerate(face_gaps(model, contacts, obs))
            if j != exclude and contacts.active[j] and contacts.posture.faces[j] == face]
    return float(np.mean(gaps)) if gaps else 0.0


def found_model(model: HandModel, contacts, obs) -> HandModel:
    """``model`` with a pole as wide as its fingertips find it (``face_gap`` of each long face).
    A grasp planned for after a move (a slide's end, a flip's landing) is judged on it: on a
    pole thinner than modelled the friction's lever is shorter, and a grasp the nominal width
    holds may not hold it. A cube, or a pole with a long face no tip touches, keeps the nominal
    model."""
    touched = {f for f, on in zip(contacts.posture.faces, contacts.active, strict=True) if on}
    if not elongated(model) or not {Face.LEFT, Face.RIGHT} <= touched:
        return model
    return model.widened(0.5 * (face_gap(model, contacts, Face.LEFT, obs)
                                + face_gap(model, contacts, Face.RIGHT, obs)))


def strict_hold(model: HandModel, contacts: Contacts, gains: PrimitivesConfig,
                firm: bool = False) -> bool:
    """True when ``contacts`` (as commanded, active fingers only) admit a squeeze strictly inside
    the friction cones: the grasp holds whatever the small wrenches a controller asks for.
    ``firm``: with a slack of at least ``gains.min_grasp_margin`` too, what a primitive asks of
    the grasp it ends in (``firm_enough``)."""
    act = [i for i in range(3) if contacts.active[i]]
    pts, nrm = contact_frames(model.shape, contacts, np.zeros(3))
    return has_strict_squeeze(grasp_matrix(pts[act], nrm[act]), model.mu * gains.friction_margin,
                              gains.min_grasp_margin if firm else 0.0)


def firm_enough(squeeze: Squeeze, gains: PrimitivesConfig) -> bool:
    """False for a grasp with a strict squeeze whose slack (``Squeeze.margin``: the least
    slack, per newton of total squeeze, of the squeeze deepest inside the cones) is below
    ``gains.min_grasp_margin``. Such a grasp holds the object at rest only with a squeeze tens
    of times its weight, its forces on the edge of the cones, and the least wrench the
    controller asks for on top (a pose error of a millimetre) needs more: moved in that state,
    the object is shot out of the hand. A grasp without a strict squeeze (held by gravity, or
    by two fingers) is judged by its force plans alone."""
    return not squeeze.usable or squeeze.margin >= gains.min_grasp_margin


# How far one unit repose (1 cm, 0.1 rad) can roll a grasp's squeeze slack down, with room:
# over 1,882 random reposes of the workspace it took at most 0.048
# (test_one_repose_rolls_the_slack_down_by_less_than_roll_reach)
ROLL_REACH = 0.1


def rolled_levers(model: HandModel, plan: GraspPlan, q: np.ndarray, q_end: dict[int, np.ndarray],
                  dtheta: float) -> np.ndarray:
    """The contact points (object frame, as ``plan.levers_O``) after a move that turns the
    object by ``dtheta`` and brings finger ``i``'s joints from ``q`` to ``q_end[i]``.

    A fingertip is a ball fixed to its distal link, and a 2-joint finger cannot choose the
    link's angle: it follows from where the tip is. So the ball turns against the object by
    ``alpha`` = the link's turn minus the object's, and, held by static friction, rolls: its
    centre moves ``r alpha`` along the face (normal turned 90 deg, the way the angles turn),
    and the contact with it. A repose of 0.1 rad moves a contact 2-3 mm this way, enough to
    take a grasp from firm to weak in a few reposes. With the joints a repose ended at, within
    0.1 mm of the simulated contacts; with those it planned, within 0.5 mm
    (``test_a_repose_rolls_the_tips_as_predicted``)."""
    r = model.tip_radius
    levers = plan.levers_O.copy()
    for k, i in enumerate(plan.fingers):
        turn = (q_end[i][0] + q_end[i][1]) - (q[2 * i] + q[2 * i + 1]) - dtheta
        alpha = (turn + math.pi) % (2 * math.pi) - math.pi
        nx, nz = plan.normals_O[k]  # inward: the outward normal turned 90 deg is (n_z, -n_x)
        levers[k] += r * alpha * np.array([nz, -nx])
    return levers


def landing_span(model: HandModel, contacts: Contacts, finger: int, face, gains: PrimitivesConfig,
                 firm: bool = False) -> tuple[float, float] | None:
    """Bounds on the coordinates along ``face`` where ``finger`` can join the other contacts in
    a grasp that ``strict_hold`` accepts (with ``firm``: ``strict_hold(..., firm=True)``; two
    LPs, ``forces.strict_span``): a search over landing places can skip everything outside
    them. None: no place on ``face`` will do."""
    at0 = contacts.moved(finger, coord=0.0, face=face)
    act = [i for i in range(3) if at0.active[i]]
    pts, nrm = contact_frames(model.shape, at0, np.zeros(3))
    inward, along = face_axes(face)
    G0 = grasp_matrix(pts[act], nrm[act])
    return strict_span(G0, 2 * act.index(finger), cross2(along, inward),
                       model.mu * gains.friction_margin, model.shape.half_extent(face) + 1.0,
                       gains.min_grasp_margin if firm else 0.0)


def min_jerk(start: np.ndarray, goal: np.ndarray, duration: float, t: float
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, velocity and acceleration of a minimum-jerk path at time ``t``."""
    if t >= duration:
        z = np.zeros_like(start)
        return goal.copy(), z, z
    p, v, a = _min_jerk_shape(t / duration)
    d = goal - start
    return start + d * p, d * v / duration, d * a / duration**2


def min_jerk_1d(start: float, goal: float, duration: float, t: float
                ) -> tuple[float, float, float]:
    """``min_jerk`` of one coordinate, in plain floats."""
    if t >= duration:
        return goal, 0.0, 0.0
    p, v, a = _min_jerk_shape(t / duration)
    d = goal - start
    return start + d * p, d * v / duration, d * a / duration**2


def _min_jerk_shape(s: float) -> tuple[float, float, float]:
    """The minimum-jerk polynomial and its first two derivatives at phase ``s`` in [0, 1)."""
    return (10 * s**3 - 15 * s**4 + 6 * s**5, 30 * s**2 - 60 * s**3 + 30 * s**4,
            60 * s - 180 * s**2 + 120 * s**3)


def object_wrench(model: HandModel, gains: PrimitivesConfig, pose: np.ndarray, twist: np.ndarray,
                  ref: tuple[np.ndarray, np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Desired object acceleration (world) and the contact wrench that causes it (object frame).

    The wrench is what the contacts must apply on the nominal object: ``M a + (0, m g, 0)``.
    """
    p_ref, v_ref, a_ref = (list(map(float, v)) for v in ref)  # plain floats: cheaper
    pose, twist = list(map(float, pose)), list(map(float, twist))
    kp, kd = gains.kp, gains.kd
    e_th = (p_ref[2] - pose[2] + math.pi) % (2 * math.pi) - math.pi
    ax = a_ref[0] + kd * (v_ref[0] - twist[0]) + kp * (p_ref[0] - pose[0])
    az = a_ref[1] + kd * (v_ref[1] - twist[1]) + kp * (p_ref[1] - pose[1])
    al = a_ref[2] + kd * (v_ref[2] - twist[2]) + kp * e_th
    shape = model.shape
    fx, fz = shape.mass_kg * ax, shape.mass_kg * (az + model.fingers[0].gravity)
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return (np.array([ax, az, al]),
            np.array([c * fx + s * fz, -s * fx + c * fz, shape.inertia * al]))


def contact_force(plan: GraspPlan, lam: np.ndarray, k: int, R: np.ndarray) -> np.ndarray:
    """World force (2,) that contact ``k`` of ``plan`` applies on the object."""
    n_W = R @ plan.normals_O[k]
    return lam[2 * k] * n_W + lam[2 * k + 1] * np.array([-n_W[1], n_W[0]])


SETTLED_SPEED = (0.005, 0.02)  # m/s, rad/s: an object this slow is at rest for settle_early


def at_rest(twist: np.ndarray, speed: tuple[float, float] = SETTLED_SPEED) -> bool:
    """The object slower than ``speed`` (m/s, rad/s): what ``settled`` tests ask of it."""
    return math.hypot(twist[0], twist[1]) <= speed[0] and abs(twist[2]) <= speed[1]

DAMPING = 1e-4  # damped least squares near singular finger postures


def damped_qdd(t: FingerTerms, ax: float, az: float) -> tuple[float, float]:
    """Joint accelerations giving tip acceleration ``(ax, az)``: ``J^-1 (a - dJ/dt qd)``, damped
    near singular postures (plain floats: this runs for every finger every step)."""
    bx, bz = ax - t.jdx, az - t.jdz
    a11 = t.j11 * t.j11 + t.j12 * t.j12 + DAMPING
    a12 = t.j11 * t.j21 + t.j12 * t.j22
    a22 = t.j21 * t.j21 + t.j22 * t.j22 + DAMPING
    det = a11 * a22 - a12 * a12
    yx, yz = (a22 * bx - a12 * bz) / det, (a11 * bz - a12 * bx) / det
    return t.j11 * yx + t.j21 * yz, t.j12 * yx + t.j22 * yz


def pushing_torque(t: FingerTerms, qdd1: float, qdd2: float, fx: float, fz: float,
                   ox: float, oz: float) -> tuple[float, float]:
    """``M qdd + V + g + J_c^T f``: inverse dynamics plus pushing with force ``f`` (world) at
    the contact point, offset ``(ox, oz)`` from the tip centre (plain floats)."""
    return (t.m11 * qdd1 + t.m12 * qdd2 + t.v1 + (t.j11 - oz) * fx + (t.j21 + ox) * fz,
            t.m12 * qdd1 + t.m22 * qdd2 + t.v2 + (t.j12 - oz) * fx + (t.j22 + ox) * fz)


def _terms(model: HandModel, i: int, q: np.ndarray, qd: np.ndarray) -> FingerTerms:
    return model.fingers[i].terms(q[2 * i], q[2 * i + 1], qd[2 * i], qd[2 * i + 1])


def push_torque(model: HandModel, i: int, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                f_W: np.ndarray, n_W: np.ndarray) -> np.ndarray:
    """Finger ``i``'s torques (2,): inverse dynamics for ``qdd`` plus ``J_c^T f_W``.

    ``J_c`` is the Jacobian of the contact point, a tip radius from the tip centre along the
    inward normal ``n_W``.
    """
    r = model.tip_radius
    return np.array(pushing_torque(_terms(model, i, q, qd), qdd[0], qdd[1], f_W[0], f_W[1],
                                   r * n_W[0], r * n_W[1]))


def follow_qdd(model: HandModel, i: int, q: np.ndarray, qd: np.ndarray, tip_O: np.ndarray,
               acc: np.ndarray, omega: float, R: np.ndarray) -> np.ndarray:
    """Joint accelerations moving finger ``i``'s tip like the object point at ``tip_O``."""
    rx, rz = R @ tip_O
    ax = acc[0] - acc[2] * rz - omega * omega * rx
    az = acc[1] + acc[2] * rx - omega * omega * rz
    return np.array(damped_qdd(_terms(model, i, q, qd), ax, az))


def repose_torques(model: HandModel, plan: GraspPlan, gains: PrimitivesConfig, q: np.ndarray,
                   qd: np.ndarray, pose: np.ndarray, twist: np.ndarray,
                   ref: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray | None:
    """Joint torques (6,) for the fingers in ``plan``; None when the forces are infeasible.

    ``pose``/``twist`` are the observed object state, ``ref`` the reference (pose, velocity,
    acceleration). Fingers outside the plan get zero torque (the caller drives them).
    """
    acc, w_O = object_wrench(model, gains, pose, twist, ref)
    lam = plan.squeeze.solve(w_O)
    if lam is None:
        return None
    return grasp_torques(model, plan, lam, acc, pose, twist, q, qd)


def grasp_torques(model: HandModel, plan: GraspPlan, lam: np.ndarray, acc: np.ndarray,
                  pose: np.ndarray, twist: np.ndarray, q: np.ndarray, qd: np.ndarray,
                  own: tuple[int, Callable[[FingerTerms, float, float], tuple[float, float]]]
                  | None = None) -> np.ndarray:
    """Joint torques (6,) of the fingers in ``plan``, in plain floats (the hot path): each
    pushes with its contact force ``lam`` while its tip moves like the object point it touches
    at the object's acceleration ``acc`` (world). The finger ``own[0]`` moves its tip by its
    own law instead: ``own[1](terms, cos theta, sin theta)`` gives its tip acceleration
    (world). Fingers outside the plan get zero torque."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    ax0, az0, alpha = float(acc[0]), float(acc[1]), float(acc[2])
    w2 = float(twist[2]) ** 2
    r = model.tip_radius
    tau = np.zeros(6)
    lam = lam.tolist()
    for k, (i, tx, tz, nox, noz) in enumerate(plan.floats):
        rx, rz = c * tx - s * tz, s * tx + c * tz  # R @ tip_O
        nx, nz = c * nox - s * noz, s * nox + c * noz  # R @ n_O
        fn, ft = lam[2 * k], lam[2 * k + 1]
        fx, fz = fn * nx - ft * nz, fn * nz + ft * nx  # f_n n + f_t rot90(n)
        t = model.fingers[i].terms(q[2 * i], q[2 * i + 1], qd[2 * i], qd[2 * i + 1])
        if own is not None and own[0] == i:
            ax, az = own[1](t, c, s)
        else:
            ax, az = ax0 - alpha * rz - w2 * rx, az0 + alpha * rx - w2 * rz
        qdd1, qdd2 = damped_qdd(t, ax, az)
        tau[2 * i], tau[2 * i + 1] = pushing_torque(t, qdd1, qdd2, fx, fz, r * nx, r * nz)
    return tau


FREE_KP, FREE_KD = 900.0, 60.0  # joint gains (1/s^2, 1/s) of a free finger holding still
_ZERO2 = np.zeros(2)


class Repose:
    """Primitive: move the object by ``delta`` (dx, dz, dtheta) keeping every contact.

    The reference moves along a minimum-jerk path for ``move_fraction`` of the duration, then
    holds still so the object settles. ``Repose(model, contacts, zeros, T)`` is a hold.

    A turn is refused when the grasp's forces cannot hold the object at the target angle:
    gravity turns in the object's frame, and a grasp that holds at the start may not (a cube
    on two tips at a corner fell so).

    A finger out of contact (a cube's released finger) holds its joints where they are, out of
    the object's way: a move that would bring the object within ``model.clearance`` of it (its
    links or its tip) is refused. Left limp, it fell to its joint limits, from where no landing
    could reach the object again.
    """

    def __init__(self, model: HandModel, contacts, delta: np.ndarray, duration_s: float,
                 gains: PrimitivesConfig | None = None, move_fraction: float = 0.7,
                 tol: tuple[float, float] = (0.002, 0.02)):
        self.model, self.contacts, self.delta = model, contacts, np.asarray(delta, float)
        self.duration_s, self.gains = duration_s, gains or PrimitivesConfig()
        self.move_s = move_fraction * duration_s
        self.tol = tol

    def start(self, obs) -> str | None:
        self.plan = plan_for(self.model, self.contacts, obs, self.gains)
        _, w_O = object_wrench(self.model, self.gains, obs.pose, np.zeros(3),
                               (obs.pose, np.zeros(3), np.zeros(3)))
        if self.plan.squeeze.solve(w_O) is None:
            return "no contact forces inside the friction cones hold the object here"
        if not firm_enough(self.plan.squeeze, self.gains):
            return (f"the grasp is too weak to move the object (squeeze slack "
                    f"{self.plan.squeeze.margin:.3f} < {self.gains.min_grasp_margin})")
        self.origin = obs.pose.copy()
        self.goal = self.origin + self.delta
        if self.model.palm_gap(self.goal) < self.model.clearance:
            return "the object would come down onto the palm"
        if self.delta[2]:  # gravity turns in the object's frame: the grasp must hold there too
            _, w_end = object_wrench(self.model, self.gains, self.goal, np.zeros(3),
                                     (self.goal, np.zeros(3), np.zeros(3)))
            if self.plan.squeeze.solve(w_end) is None:
                return "no contact forces inside the friction cones hold the object at the " \
                       "target angle"
        R = rotation(self.goal[2])
        gaps = face_gaps(self.model, self.contacts, obs)
        q_end = {}
        for k, i in enumerate(self.plan.fingers):
            tip = self.goal[:2] + R @ self.plan.tips_O[k]
            qi = self.model.fingers[i].ik(tip, 1 if obs.q[2 * i + 1] >= 0 else -1)
            if qi is None:
                return f"finger {i} cannot follow the object to the target pose"
            # its links against the face where its tip touches it (a thinner or thicker
            # object, an error of the observed pose), not the nominal face
            at = face_shifted(self.goal, self.plan.normals_O[k], gaps[i])
            if self.model.finger_gap(i, qi, at) < self.model.clearance:
                return f"finger {i}'s links would cut into the object at the target pose"
            q_end[i] = qi
        self.q_end = q_end  # each finger's joints at the target pose, as planned
        self.free = [i for i in range(3) if not self.contacts.active[i]]
        self.q_free = obs.q.copy()
        for i in self.free:
            qi = self.q_free[2 * i:2 * i + 2]
            for s in (0.5, 1.0):
                if self.model.free_finger_gap(i, qi, self.origin + s * self.delta) < \
                        self.model.clearance:
                    return f"free finger {i} would be in the object's way"
        return self._ends_firm(obs, q_end)

    def _ends_firm(self, obs, q_end: dict[int, np.ndarray]) -> str | None:
        """Refuse a move whose tips would roll (``rolled_levers``) into a weak grasp: one that
        no primitive may move again (``firm_enough``), a dead end. Its LP is solved only for a
        grasp within ``ROLL_REACH`` of the margin (no unit repose rolls the slack further)."""
        least = self.gains.min_grasp_margin
        if (not self.delta.any() or least <= 0 or not self.plan.squeeze.usable
                or self.plan.squeeze.margin >= least + ROLL_REACH):
            return None
        levers = rolled_levers(self.model, self.plan, obs.q, q_end, float(self.delta[2]))
        slack = squeeze_margin(grasp_matrix(levers, self.plan.normals_O),
                               self.model.mu * self.gains.friction_margin)
        if slack < least:
            return (f"the grasp would end too weak to move again: its tips roll on the faces "
                    f"to a squeeze slack of {slack:.3f} < {least}")
        return None

    def achieved(self, obs) -> str | None:
        """Within ``tol`` (m, rad) of the goal, as observed."""
        err = obs.pose - self.goal
        e_m, e_rad = math.hypot(err[0], err[1]), abs((err[2] + math.pi) % (2 * math.pi) - math.pi)
        if e_m <= self.tol[0] and e_rad <= self.tol[1]:
            return None
        return f"pose error {e_m * 1e3:.1f} mm, {e_rad:.3f} rad"

    def settled(self, obs) -> bool:
        """Past the move, within ``tol`` of the goal and at rest (``at_rest``)."""
        return obs.t >= self.move_s and at_rest(obs.twist) and self.achieved(obs) is None

    def torques(self, obs) -> np.ndarray | None:
        ref = min_jerk(self.origin, self.goal, self.move_s, obs.t)
        tau = repose_torques(self.model, self.plan, self.gains, obs.q, obs.qd, obs.pose,
                             obs.twist, ref)
        if tau is not None:
            for i in self.free:  # hold still where it is
                j = slice(2 * i, 2 * i + 2)
                qdd = FREE_KP * (self.q_free[j] - obs.q[j]) - FREE_KD * obs.qd[j]
                tau[j] = push_torque(self.model, i, obs.q, obs.qd, qdd, _ZERO2, _ZERO2)
        return tau
