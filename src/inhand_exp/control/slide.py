"""Slide (paper eq. 6): one fingertip moves along its face while the other two hold the object.

The sliding finger's tip follows a target that moves along the face (in the object frame,
mapped through the observed pose) by inverse dynamics: a PD along the face, while across it the
tip moves with the object and the planned normal force does the pressing. While it
moves, its contact force lies on the edge of the friction cone (kinetic friction dragging the
object along): the force distribution plans for that drag, so the other two fingers hold the
object against it and the sliding finger's torques push through it. The object is held at its
start pose exactly as in a hold.
"""

from __future__ import annotations

import math

import numpy as np

from inhand_exp.config import PrimitivesConfig
from inhand_exp.control.grasp import Contacts, face_axes, face_shifted, rotation
from inhand_exp.control.hand import HandModel
from inhand_exp.control.repose import (
    GraspPlan,
    at_rest,
    contact_force,
    damped_qdd,
    follow_qdd,
    min_jerk,
    object_wrench,
    plan_for,
    push_torque,
    strict_hold,
)

REPLAN_M = 0.005  # the sliding tip's travel along its face after which its plans are made again
MAX_PUSH_N = 1.5  # the most a sliding finger presses (N): more, and its friction drags the object


def drag_of(model: HandModel, face, dc: float) -> float:
    """The sliding finger's tangential force per newton of normal force (kinetic friction,
    opposing its motion ``dc`` along ``face``), in the contact's tangent convention."""
    n_O, along_O = face_axes(face)
    t_O = np.array([-n_O[1], n_O[0]])
    return model.mu * float(np.sign(dc) * (along_O @ t_O))


def slide_forces(plan: GraspPlan, rest: GraspPlan, finger: int, angle: float, model: HandModel,
                 gains: PrimitivesConfig, max_push_n: float) -> str | None:
    """Why the other fingers cannot hold the object at rest at ``angle`` while ``finger``
    slides (``plan``, with its drag) and once it stops (``rest``); None when they can.

    The sliding finger presses as lightly as the plan allows, and no harder than
    ``max_push_n``: its friction would drag the object. Near upright, the lone finger of a
    pole cannot slide down at all: the pair on the other face would carry the weight and the
    drag with friction bounded by the same normal force.
    """
    pose = np.array([0.0, 0.0, angle])
    _, w_O = object_wrench(model, gains, pose, np.zeros(3), (pose, np.zeros(3), np.zeros(3)))
    lam = plan.squeeze.solve(w_O)
    if lam is None or rest.squeeze.solve(w_O) is None:
        return f"the other fingers cannot hold the object while finger {finger} slides"
    k = plan.fingers.index(finger)
    if lam[2 * k] > max_push_n:
        return (f"finger {finger} would have to press with {lam[2 * k]:.2f} N to slide: its "
                f"friction would drag the object")
    return None


class Slide:
    """Primitive: move ``finger``'s contact by ``dc`` metres along its face."""

    def __init__(self, model: HandModel, contacts: Contacts, finger: int, dc: float,
                 duration_s: float, gains: PrimitivesConfig | None = None, kp: float = 900.0,
                 kd: float = 60.0, move_fraction: float = 0.7,
                 max_push_n: float = MAX_PUSH_N, min_bend: float = 0.3):
        self.model, self.contacts, self.finger, self.dc = model, contacts, finger, dc
        self.duration_s, self.gains = duration_s, gains or PrimitivesConfig()
        self.kp, self.kd = kp, kd
        self.move_s = move_fraction * duration_s
        self.max_push = max_push_n
        self.min_bend = min_bend  # |sin q2| at the end: away from the straight-finger singularity

    def start(self, obs) -> str | None:
        model, c, i = self.model, self.contacts, self.finger
        if not c.active[i]:
            return f"finger {i} is not in contact"
        face = c.posture.faces[i]
        self.n_O, self.along_O = face_axes(face)
        # the geometric checks first: they cost microseconds, the force plans milliseconds
        R = rotation(obs.pose[2])
        # where the face really is: the tip touches it, so its gap to the nominal face is the
        # face's offset (a thinner or thicker object, the held error of the observed pose)
        self.gap0, self.c0 = model.surface_gap(i, face, obs.pose, obs.q)
        self.c1 = self.c0 + self.dc
        limit = model.shape.half_extent(face) - model.tip_radius
        if abs(self.c1) > limit:
            return f"finger {i} would slide past the end of its face ({self.c1:+.3f} m)"
        if abs(self.c1) > limit - self.gains.end_margin_m and abs(self.c1) > abs(self.c0):
            return (f"finger {i} would slide within {self.gains.end_margin_m * 1e3:.0f} mm "
                    f"of the end of its face ({self.c1:+.3f} m)")
        self.elbow = 1 if obs.q[2 * i + 1] >= 0 else -1
        surface, _ = model.shape.local_contact(face, self.c1)
        end = obs.pose[:2] + R @ (surface - (model.tip_radius + self.gap0) * self.n_O)
        q_end = model.fingers[i].ik(end, self.elbow)
        if q_end is None:
            return f"finger {i} cannot reach the end of the slide"
        if abs(np.sin(q_end[1])) < self.min_bend:
            return f"finger {i} would end the slide stretched nearly straight"
        if model.finger_gap(i, q_end, face_shifted(obs.pose, self.n_O, self.gap0)) \
                < model.clearance:
            return f"finger {i}'s links would cut into the object at the end of the slide"
        drag = self.drag = drag_of(model, face, self.dc)
        self.planned_at, self.stale = self.c0, set()
        self.plan = plan_for(model, c, obs, self.gains, sliding=i, drag=drag)
        self.rest = plan_for(model, c, obs, self.gains, sliding=i)
        self.hold = plan_for(model, c, obs, self.gains)  # the fallback of a step
        refused = slide_forces(self.plan, self.rest, i, obs.pose[2], model, self.gains,
                               self.max_push)
        if refused:
            return refused
        if not strict_hold(model, c.moved(i, coord=self.c1), self.gains, firm=True):
            return f"the grasp after the slide of finger {i} cannot hold the object firmly"
        self.origin = obs.pose.copy()
        return None

    def achieved(self, obs, tol_m: float = 0.003) -> str | None:
        """The tip within ``tol_m`` of its target coordinate and of the face where it touched
        at the start (``gap0`` off the nominal face)."""
        gap, coord = self.model.surface_gap(self.finger, self.contacts.posture.faces[self.finger],
                                            obs.pose, obs.q)
        if abs(coord - self.c1) <= tol_m and abs(gap - self.gap0) <= tol_m:
            return None
        return (f"finger {self.finger} at {coord:+.3f} m (target {self.c1:+.3f}), "
                f"{(gap - self.gap0) * 1e3:.1f} mm off its face")

    def settled(self, obs, joint_speed: float = 0.05) -> bool:
        """Past the move, the tip at its target, the object at rest and the sliding finger's
        joints slower than ``joint_speed`` (rad/s)."""
        i = self.finger
        return (obs.t >= self.move_s and at_rest(obs.twist)
                and max(abs(obs.qd[2 * i]), abs(obs.qd[2 * i + 1])) <= joint_speed
                and self.achieved(obs) is None)

    def _mark_stale(self, obs) -> None:
        """Once the sliding tip has moved ``REPLAN_M`` along its face since the force plans
        were made, mark them to be made again at the tips as measured: a plan's levers are
        where the tips were, and a grasp whose torque rests on the friction across a narrow
        face (a pole thinner than modelled) tips over on levers a slide's length stale."""
        i = self.finger
        dx, dz = self.model.fingers[i].tip(obs.q[2 * i:2 * i + 2]) - obs.pose[:2]
        c, s = math.cos(obs.pose[2]), math.sin(obs.pose[2])
        coord = self.along_O[0] * (c * dx + s * dz) + self.along_O[1] * (c * dz - s * dx)
        if abs(coord - self.planned_at) >= REPLAN_M:
            self.planned_at, self.stale = coord, {"plan", "rest", "hold"}

    def _planned(self, name: str, obs) -> GraspPlan:
        """The force plan ``name`` (``plan``, ``rest`` or ``hold``), made again if stale."""
        if name in self.stale:
            self.stale.discard(name)
            kw = {"plan": {"sliding": self.finger, "drag": self.drag},
                  "rest": {"sliding": self.finger}, "hold": {}}[name]
            setattr(self, name, GraspPlan.from_state(self.model, self.contacts, obs.pose,
                                                     obs.q, self.gains, **kw))
        return getattr(self, name)

    def torques(self, obs) -> np.ndarray | None:
        model, i = self.model, self.finger
        self._mark_stale(obs)
        plan = self._planned("plan" if obs.t < self.move_s else "rest", obs)
        zero = np.zeros(3)
        acc, w_O = object_wrench(model, self.gains, obs.pose, obs.twist, (self.origin, zero, zero))
        lam = plan.squeeze.solve(w_O)
        sliding = True
        if lam is None:
            # the drag cannot be balanced this step: every finger holds, the sliding one with
            # static friction too, and the slide goes on at the next step
            plan, sliding = self._planned("hold", obs), False
            lam = plan.squeeze.solve(w_O)
        if lam is None:
            return None
        R = rotation(obs.pose[2])
        tau = np.zeros(6)
        for k, j in enumerate(plan.fingers):
            f_W, n_W = contact_force(plan, lam, k, R), R @ plan.normals_O[k]
            if j == i and sliding:
                qdd = self._slide_qdd(obs, R, acc)
            else:
                qdd = follow_qdd(model, j, obs.q, obs.qd, plan.tips_O[k], acc, obs.twist[2], R)
            tau[2 * j:2 * j + 2] = push_torque(model, j, obs.q, obs.qd, qdd, f_W, n_W)
        return tau

    def _slide_qdd(self, obs, R: np.ndarray, acc: np.ndarray) -> np.ndarray:
        """Inverse dynamics towards the moving target: stiff along the face, force across it.

        Along the face the tip tracks the minimum-jerk target with a PD; across it, the tip
        moves with the object (as a holding finger does) and the planned normal force presses.
        """
        model, i = self.model, self.finger
        finger = model.fingers[i]
        c, cd, cdd = min_jerk(np.array([self.c0]), np.array([self.c1]), self.move_s, obs.t)
        along_W = R @ self.along_O
        surface_O, _ = model.shape.local_contact(self.contacts.posture.faces[i], float(c[0]))
        target_W = obs.pose[:2] + R @ (surface_O - model.tip_radius * self.n_O)
        qi, qdi = obs.q[2 * i:2 * i + 2], obs.qd[2 * i:2 * i + 2]
        t = finger.terms(qi[0], qi[1], qdi[0], qdi[1])
        tip = np.array([t.x, t.z])
        v_tip = np.array([t.j11 * qdi[0] + t.j12 * qdi[1], t.j21 * qdi[0] + t.j22 * qdi[1]])
        r = tip - obs.pose[:2]
        omega = obs.twist[2]
        v_obj = obs.twist[:2] + omega * np.array([-r[1], r[0]])  # object point at the tip
        a_obj = acc[:2] + acc[2] * np.array([-r[1], r[0]]) - omega**2 * r
        e_t = float(along_W @ (target_W - tip))
        ed_t = float(cd[0]) - float(along_W @ (v_tip - v_obj))
        a_tip = a_obj + along_W * (float(cdd[0]) + self.kp * e_t + self.kd * ed_t)
        return np.array(damped_qdd(t, a_tip[0], a_tip[1]))
