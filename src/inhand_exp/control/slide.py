"""Slide (paper eq. 6): one fingertip moves along its face while the other two hold the object.

The sliding finger follows an inverse-kinematics target that moves along the face (in the
object frame, mapped through the observed pose) with joint-space inverse dynamics. While it
moves, its contact force lies on the edge of the friction cone (kinetic friction dragging the
object along): the force distribution plans for that drag, so the other two fingers hold the
object against it and the sliding finger's torques push through it. The object is held at its
start pose exactly as in a hold.
"""

from __future__ import annotations

import numpy as np

from inhand_exp.control.forces import Squeeze
from inhand_exp.control.grasp import Contacts, contact_frames, face_axes, grasp_matrix, rotation
from inhand_exp.control.hand import HandModel
from inhand_exp.control.repose import (
    Gains,
    GraspPlan,
    contact_force,
    follow_qdd,
    min_jerk,
    object_wrench,
    push_torque,
)


def holds(model: HandModel, contacts: Contacts, gains: Gains) -> bool:
    """True when ``contacts`` (as commanded) admit a squeeze inside the friction cones."""
    pts, nrm = contact_frames(model.shape, contacts, np.zeros(3))
    act = [i for i in range(3) if contacts.active[i]]
    G = grasp_matrix(pts[act], nrm[act])
    return Squeeze.build(G, model.mu * gains.friction_margin, gains.f_min).usable


class Slide:
    """Primitive: move ``finger``'s contact by ``dc`` metres along its face."""

    def __init__(self, model: HandModel, contacts: Contacts, finger: int, dc: float,
                 duration_s: float, gains: Gains | None = None, kp_joint: float = 900.0,
                 kd_joint: float = 60.0, press_m: float = 0.001, move_fraction: float = 0.7):
        self.model, self.contacts, self.finger, self.dc = model, contacts, finger, dc
        self.duration_s, self.gains = duration_s, gains or Gains()
        self.kp, self.kd, self.press = kp_joint, kd_joint, press_m
        self.move_s = move_fraction * duration_s

    def start(self, obs) -> str | None:
        model, c, i = self.model, self.contacts, self.finger
        if not c.active[i]:
            return f"finger {i} is not in contact"
        face = c.posture.faces[i]
        self.n_O, self.along_O = face_axes(face)
        t_O = np.array([-self.n_O[1], self.n_O[0]])
        drag = model.mu * float(np.sign(self.dc) * (self.along_O @ t_O))
        self.plan = GraspPlan.from_state(model, c, obs.pose, obs.q, self.gains, sliding=i,
                                         drag=drag)
        self.rest = GraspPlan.from_state(model, c, obs.pose, obs.q, self.gains, sliding=i)
        _, w_O = object_wrench(model, self.gains, obs.pose, np.zeros(3),
                               (obs.pose, np.zeros(3), np.zeros(3)))
        if self.plan.squeeze.solve(w_O) is None or self.rest.squeeze.solve(w_O) is None:
            return f"the other fingers cannot hold the object while finger {i} slides"
        k = self.plan.fingers.index(i)
        self.c0 = model.shape.coord_of(face, self.plan.levers_O[k])
        self.c1 = self.c0 + self.dc
        limit = model.shape.half_extent(face) - model.tip_radius
        if abs(self.c1) > limit:
            return f"finger {i} would slide past the end of its face ({self.c1:+.3f} m)"
        if not holds(model, c.moved(i, coord=self.c1), self.gains):
            return f"the grasp after the slide of finger {i} cannot hold the object"
        self.origin = obs.pose.copy()
        self.elbow = 1 if obs.q[2 * i + 1] >= 0 else -1
        return None

    def torques(self, obs) -> np.ndarray | None:
        model, i = self.model, self.finger
        plan = self.plan if obs.t < self.move_s else self.rest
        zero = np.zeros(3)
        acc, w_O = object_wrench(model, self.gains, obs.pose, obs.twist, (self.origin, zero, zero))
        lam = plan.squeeze.solve(w_O)
        if lam is None:
            return None
        R = rotation(obs.pose[2])
        tau = np.zeros(6)
        for k, j in enumerate(plan.fingers):
            f_W, n_W = contact_force(plan, lam, k, R), R @ plan.normals_O[k]
            if j == i:
                qdd = self._slide_qdd(obs, R)
            else:
                qdd = follow_qdd(model, j, obs.q, obs.qd, plan.tips_O[k], acc, obs.twist[2], R)
            tau[2 * j:2 * j + 2] = push_torque(model, j, obs.q, obs.qd, qdd, f_W, n_W)
        return tau

    def _slide_qdd(self, obs, R: np.ndarray) -> np.ndarray:
        """Joint-space PD towards the IK solution of the moving tip target."""
        model, i = self.model, self.finger
        finger = model.fingers[i]
        c, cd, _ = min_jerk(np.array([self.c0]), np.array([self.c1]), self.move_s, obs.t)
        face = self.contacts.posture.faces[i]
        surface_O, _ = model.shape.local_contact(face, float(c[0]))
        target_O = surface_O - (model.tip_radius - self.press) * self.n_O
        target_W = obs.pose[:2] + R @ target_O
        qi, qdi = obs.q[2 * i:2 * i + 2], obs.qd[2 * i:2 * i + 2]
        q_ref = finger.ik(target_W, self.elbow)
        if q_ref is None:
            q_ref = qi
        J = finger.jacobian(q_ref)
        qd_ref = np.linalg.solve(J, R @ self.along_O * float(cd[0])) \
            if abs(np.linalg.det(J)) > 1e-6 else np.zeros(2)
        return self.kp * (q_ref - qi) + self.kd * (qd_ref - qdi)
