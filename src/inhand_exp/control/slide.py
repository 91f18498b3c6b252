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

import functools
import math

import numpy as np

from inhand_exp.config import PrimitivesConfig
from inhand_exp.control.finger import FingerTerms
from inhand_exp.control.grasp import Contacts, face_axes, face_shifted, rotation
from inhand_exp.control.hand import HandModel
from inhand_exp.control.repose import (
    GraspPlan,
    at_rest,
    found_model,
    grasp_torques,
    min_jerk_1d,
    object_wrench,
    plan_for,
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
        self._face = (tuple(map(float, self.n_O)), tuple(map(float, self.along_O)),
                      model.shape.depth(face), model.tip_radius)  # inward, along, depth, radius
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
        if not strict_hold(found_model(model, c, obs), c.moved(i, coord=self.c1), self.gains,
                           firm=True):
            return f"the grasp after the slide of finger {i} cannot hold the object firmly"
        self.origin = obs.pose.copy()
        self.halted = False  # set once a step's plan pinches (``_pinches``)
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
        self._mark_stale(obs)
        plan = self._planned("plan" if obs.t < self.move_s else "rest", obs)
        zero = np.zeros(3)
        acc, w_O = object_wrench(self.model, self.gains, obs.pose, obs.twist,
                                 (self.origin, zero, zero))
        lam = None if self.halted else plan.squeeze.solve(w_O)
        own = (self.finger, functools.partial(self._tip_acc, obs, acc))
        if lam is not None and self._pinches(plan, lam):
            self.halted, lam = True, None  # the slide stops here and holds to its end
        if lam is None:
            # the drag cannot be balanced this step: every finger holds, the sliding one with
            # static friction too, and the slide goes on at the next step (unless halted)
            plan, own = self._planned("hold", obs), None
            lam = plan.squeeze.solve(w_O)
        if lam is None:
            return None
        return grasp_torques(self.model, plan, lam, acc, obs.pose, obs.twist, obs.q, obs.qd, own)

    def _pinches(self, plan: GraspPlan, lam: np.ndarray) -> bool:
        """True when ``lam`` asks a holding finger for more normal force than
        ``gains.slide_max_normal_force_n``. Where the slide's drag can be balanced only by
        pinching (the holding tips nearly opposite each other, the torque resting on friction
        across the faces: on a pole thinner than modelled, once the sliding tip has moved), the
        least-force plan jumps from a few newtons to 40-50 and the object leaves the hand."""
        cap, k = self.gains.slide_max_normal_force_n, plan.fingers.index(self.finger)
        # (the slide then halts: its tip stays where it is and every finger holds the object
        # for the rest of its duration, which ends it as a timeout short of its target)
        return any(lam[2 * j] > cap for j in range(len(plan.fingers)) if j != k)

    def _tip_acc(self, obs, acc: np.ndarray, t: FingerTerms, c: float, s: float
                 ) -> tuple[float, float]:
        """The sliding tip's acceleration (world): stiff along the face, force across it.

        Along the face the tip tracks the minimum-jerk target with a PD; across it, the tip
        moves with the object (as a holding finger does) and the planned normal force presses.
        ``t``: the finger's terms, ``c``, ``s``: the object's cos and sin (plain floats).
        """
        i = self.finger
        coord, cd, cdd = min_jerk_1d(self.c0, self.c1, self.move_s, obs.t)
        (nx, nz), (lx, lz), depth, r = self._face
        # the target: the tip centre a radius off the face at ``coord`` (object frame)
        px, pz = -nx * depth + lx * coord - r * nx, -nz * depth + lz * coord - r * nz
        x, z, th_dot = float(obs.pose[0]), float(obs.pose[1]), float(obs.twist[2])
        ux, uz = c * lx - s * lz, s * lx + c * lz  # along the face, world
        qd1, qd2 = float(obs.qd[2 * i]), float(obs.qd[2 * i + 1])
        vx, vz = t.j11 * qd1 + t.j12 * qd2, t.j21 * qd1 + t.j22 * qd2  # the tip's velocity
        rx, rz = t.x - x, t.z - z
        w2 = th_dot**2
        # the object point at the tip: its velocity and acceleration
        bx, bz = float(obs.twist[0]) - th_dot * rz, float(obs.twist[1]) + th_dot * rx
        ax = float(acc[0]) - float(acc[2]) * rz - w2 * rx
        az = float(acc[1]) + float(acc[2]) * rx - w2 * rz
        e_t = ux * (x + c * px - s * pz - t.x) + uz * (z + s * px + c * pz - t.z)
        ed_t = cd - (ux * (vx - bx) + uz * (vz - bz))
        push = cdd + self.kp * e_t + self.kd * ed_t
        return ax + ux * push, az + uz * push
