"""Flip (pole): take one finger off its face, carry it round the end, put it on the other face.

Phases, as fractions of the duration: unload (the flipping finger's share of the contact force
ramps to zero while the other two take the whole load), travel (the free tip follows waypoints
fixed in the object frame: lift clear of the face, round the nearer end, across to the other
face; joint-space inverse dynamics to an inverse-kinematics target, as in a slide), touch (the tip
presses onto the new face), load (the force distribution is planned again from the measured
contacts and ramps from two contacts to three), settle. The two fingers that stay must hold the
object alone: they must push from opposite faces, and the two-contact force problem must be
feasible. The object is held at its start pose throughout.
"""

from __future__ import annotations

import numpy as np

from inhand_exp.control.forces import Squeeze
from inhand_exp.control.grasp import (
    Contacts,
    Face,
    contact_frames,
    face_axes,
    grasp_matrix,
    rotation,
)
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

OPPOSITE = {Face.TOP: Face.BOTTOM, Face.BOTTOM: Face.TOP,
            Face.LEFT: Face.RIGHT, Face.RIGHT: Face.LEFT}
PHASES = {"unload": 0.12, "travel": 0.55, "touch": 0.1, "load": 0.1}  # rest settles


class Flip:
    """Primitive: move ``finger`` to the opposite face.

    It lands at the coordinate nearest its present one where the new grasp admits a squeeze
    strictly inside the friction cones (a grasp that only gravity makes feasible proved fragile
    while the force is handed over) and where the whole path is reachable.
    """

    def __init__(self, model: HandModel, contacts: Contacts, finger: int, duration_s: float,
                 gains: Gains | None = None, clearance_m: float = 0.025, press_m: float = 0.001,
                 kp_joint: float = 900.0, kd_joint: float = 60.0):
        self.model, self.contacts, self.finger = model, contacts, finger
        self.duration_s, self.gains = duration_s, gains or Gains()
        self.clearance, self.press = clearance_m, press_m
        self.kp, self.kd = kp_joint, kd_joint
        t, self.times = 0.0, {}
        for name, frac in PHASES.items():
            self.times[name] = (t, t + frac * duration_s)
            t += frac * duration_s

    @property
    def result(self) -> Contacts:
        """The contact configuration the flip aims for."""
        face = OPPOSITE[self.contacts.posture.faces[self.finger]]
        return self.contacts.moved(self.finger, coord=self.coord, face=face)

    def start(self, obs) -> str | None:
        model, c, i = self.model, self.contacts, self.finger
        others = [j for j in range(3) if j != i]
        if not all(c.active[j] for j in range(3)):
            return "every finger must be in contact before a flip"
        faces = [c.posture.faces[j] for j in others]
        if faces[0] != OPPOSITE[faces[1]]:
            return f"fingers {others} do not oppose each other"
        self.full = GraspPlan.from_state(model, c, obs.pose, obs.q, self.gains)
        self.pair = GraspPlan.from_state(model, c.moved(i, active=False), obs.pose, obs.q,
                                         self.gains)
        zero = np.zeros(3)
        _, w_O = object_wrench(model, self.gains, obs.pose, zero, (obs.pose, zero, zero))
        if self.full.squeeze.solve(w_O) is None or self.pair.squeeze.solve(w_O) is None:
            return f"fingers {others} cannot hold the object alone"
        k = self.full.fingers.index(i)
        face = c.posture.faces[i]
        self.contacts = model.measured(c, obs.pose, obs.q)
        self.elbow = 1 if obs.q[2 * i + 1] >= 0 else -1
        self.origin = obs.pose.copy()
        found = self._landing(obs, self.full.tips_O[k], face)
        if found is None:
            return f"no reachable landing on the other face holds the object for finger {i}"
        self.coord, self.path = found
        self.loaded: GraspPlan | None = None
        return None

    def _landing(self, obs, tip_O: np.ndarray, face: Face,
                 step_m: float = 0.005) -> tuple[float, list[np.ndarray]] | None:
        """The landing coordinate and its path, nearest the present coordinate first."""
        model, i = self.model, self.finger
        new_face = OPPOSITE[face]
        here = self.contacts.coords[i]
        limit = model.shape.half_extent(new_face) - 2 * model.tip_radius
        n = int(limit // step_m)
        candidates = sorted((k * step_m for k in range(-n, n + 1)), key=lambda c: abs(c - here))
        R = rotation(obs.pose[2])
        for coord in candidates:
            result = self.contacts.moved(i, coord=coord, face=new_face)
            pts, nrm = contact_frames(model.shape, result, np.zeros(3))
            sq = Squeeze.build(grasp_matrix(pts, nrm), model.mu * self.gains.friction_margin,
                               self.gains.f_min, self.gains.f_max)
            if not sq.usable:
                continue
            self.coord = coord
            path = self._waypoints(tip_O, face)
            if all(model.fingers[i].ik(obs.pose[:2] + R @ p, self.elbow) is not None
                   for p in self._dense_path(path)):
                return coord, path
        return None

    def _waypoints(self, tip_O: np.ndarray, face: Face) -> list[np.ndarray]:
        """Tip-centre waypoints in the object frame, from the current contact to the new one."""
        shape, r = self.model.shape, self.model.tip_radius
        new_face = OPPOSITE[face]
        lift = r + self.clearance
        inward, along = face_axes(face)
        out_old, out_new = -inward, inward
        # round the end nearer the finger's base
        base_x = self.model.fingers[self.finger].base_x
        ends_x = [self.origin[0] + (rotation(self.origin[2]) @ (e * along))[0] for e in (-1, 1)]
        end = -1.0 if abs(ends_x[0] - base_x) <= abs(ends_x[1] - base_x) else 1.0
        reach_end = shape.half_extent(face) + lift
        half_depth = abs(shape.local_contact(face, 0.0)[0] @ out_old)
        surface_new, _ = shape.local_contact(new_face, self.coord)
        return [tip_O,
                tip_O + self.clearance * out_old,
                along * end * reach_end + out_old * (half_depth + lift),
                along * end * reach_end + out_new * (half_depth + lift),
                surface_new + out_new * lift,
                surface_new + out_new * (r - self.press)]

    @staticmethod
    def _dense_path(path: list[np.ndarray], n: int = 8) -> list[np.ndarray]:
        pts = []
        for a, b in zip(path, path[1:], strict=False):
            pts += [a + (b - a) * s for s in np.linspace(0, 1, n)]
        return pts

    def _travel_target(self, t: float) -> np.ndarray:
        """Tip-centre target in the object frame at time ``t``.

        Each straight segment between waypoints is its own minimum-jerk move, with time in
        proportion to its length, so the tip stops at every corner instead of cutting it.
        """
        t0, t1 = self.times["travel"][0], self.times["touch"][1]
        if t <= t0:
            return self.path[0]
        lengths = [float(np.linalg.norm(b - a)) for a, b in zip(self.path, self.path[1:],
                                                                 strict=False)]
        total = sum(lengths) or 1.0
        elapsed = t - t0
        for a, b, seg in zip(self.path, self.path[1:], lengths, strict=False):
            span = (t1 - t0) * seg / total
            if elapsed <= span:
                return min_jerk(a, b, span, elapsed)[0]
            elapsed -= span
        return self.path[-1]

    def torques(self, obs) -> np.ndarray | None:
        model, i, t = self.model, self.finger, obs.t
        zero = np.zeros(3)
        acc, w_O = object_wrench(model, self.gains, obs.pose, obs.twist, (self.origin, zero, zero))
        R = rotation(obs.pose[2])
        un0, un1 = self.times["unload"]
        ld0, ld1 = self.times["load"]
        if t < un1:  # blend three contacts -> the pair
            s = (t - un0) / (un1 - un0)
            mix = [(self.full, 1 - s), (self.pair, s)]
        elif t < ld0:
            mix = [(self.pair, 1.0)]
        else:
            if self.loaded is None:
                self.loaded = GraspPlan.from_state(model, self.result, obs.pose, obs.q,
                                                   self.gains)
            s = min(1.0, (t - ld0) / (ld1 - ld0))
            mix = [(self.pair, 1 - s), (self.loaded, s)]
        # A blend of two feasible solutions is feasible (the cones are convex); where one plan
        # has no solution for this wrench, the other carries the whole load alone.
        solved = [(plan, weight, plan.squeeze.solve(w_O)) for plan, weight in mix if weight > 0]
        solved = [(p, w, lam) for p, w, lam in solved if lam is not None]
        if not solved:
            return None
        total = sum(w for _, w, _ in solved)
        force = {j: np.zeros(2) for j in range(3)}
        normal = {}
        for plan, weight, lam in solved:
            weight /= total
            for k, j in enumerate(plan.fingers):
                force[j] += weight * contact_force(plan, lam, k, R)
                normal[j] = R @ plan.normals_O[k]
        tau = np.zeros(6)
        for k, j in enumerate(self.pair.fingers):
            qdd = follow_qdd(model, j, obs.q, obs.qd, self.pair.tips_O[k], acc, obs.twist[2], R)
            tau[2 * j:2 * j + 2] = push_torque(model, j, obs.q, obs.qd, qdd, force[j], normal[j])
        qdd = self._track_qdd(obs, R, t)
        n_i = normal.get(i, np.zeros(2))
        tau[2 * i:2 * i + 2] = push_torque(model, i, obs.q, obs.qd, qdd, force[i], n_i)
        return tau

    def _track_qdd(self, obs, R: np.ndarray, t: float, h: float = 1e-3) -> np.ndarray:
        """Joint-space PD with feed-forward along the path (finite differences of the IK)."""
        finger, i = self.model.fingers[self.finger], self.finger
        qi, qdi = obs.q[2 * i:2 * i + 2], obs.qd[2 * i:2 * i + 2]
        refs = [finger.ik(obs.pose[:2] + R @ self._travel_target(t + k * h), self.elbow)
                for k in (0, 1, 2)]
        if any(r is None for r in refs):
            return -self.kd * qdi
        q0, q1, q2 = refs
        qd_ref, qdd_ref = (q1 - q0) / h, (q2 - 2 * q1 + q0) / h**2
        return qdd_ref + self.kp * (q0 - qi) + self.kd * (qd_ref - qdi)
