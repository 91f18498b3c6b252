"""Flip (pole): take one finger off its face, carry it round the end, put it on the other face.

Phases, as fractions of the duration: unload (the flipping finger's share of the contact force
ramps to zero while the other two take the whole load), travel (the free tip follows waypoints
fixed in the object frame: lift clear of the face, round the end nearer the finger's base, across
to the other face), touch (the tip presses onto the new face), load (the force distribution is
planned again from the measured contacts and ramps from two contacts to three), settle. The two
fingers that stay must hold the object alone: they must push from opposite faces, and the
two-contact force problem must be feasible. The object is held at its start pose throughout.
"""

from __future__ import annotations

import numpy as np

from inhand_exp.control.grasp import (
    Contacts,
    Face,
    face_axes,
    rotation,
)
from inhand_exp.control.hand import HandModel
from inhand_exp.control.handover import PathTracker, blended_forces, hover, route_round
from inhand_exp.control.repose import (
    Gains,
    GraspPlan,
    follow_qdd,
    landing_span,
    object_wrench,
    plan_for,
    push_torque,
    strict_hold,
)

OPPOSITE = {Face.TOP: Face.BOTTOM, Face.BOTTOM: Face.TOP,
            Face.LEFT: Face.RIGHT, Face.RIGHT: Face.LEFT}
SPAN_TOL_M = 1e-6  # slack on landing_span's bounds (LP tolerance): they only prune the search
PHASES = {"unload": 0.12, "travel": 0.55, "touch": 0.1, "load": 0.1}  # the rest settles


def phase_times(duration_s: float, phases: dict[str, float]) -> dict[str, tuple[float, float]]:
    """Start and end (s) of each phase from its fraction of the duration."""
    t, times = 0.0, {}
    for name, frac in phases.items():
        times[name] = (t, t + frac * duration_s)
        t += frac * duration_s
    return times


def pair_holds(model: HandModel, contacts: Contacts, finger: int, obs, gains: Gains
               ) -> tuple[GraspPlan, GraspPlan] | str:
    """Plans with and without ``finger``, or why the other two cannot hold the object alone."""
    others = [j for j in range(3) if j != finger]
    if not all(contacts.active[j] for j in others):
        return f"fingers {others} must both be in contact"
    faces = [contacts.posture.faces[j] for j in others]
    if faces[0] != OPPOSITE[faces[1]]:
        return f"fingers {others} do not oppose each other"
    full = plan_for(model, contacts, obs, gains)
    pair = plan_for(model, contacts.moved(finger, active=False), obs, gains)
    zero = np.zeros(3)
    _, w_O = object_wrench(model, gains, obs.pose, zero, (obs.pose, zero, zero))
    if pair.squeeze.solve(w_O) is None or (contacts.active[finger]
                                           and full.squeeze.solve(w_O) is None):
        return f"fingers {others} cannot hold the object alone"
    return full, pair


def handover_torques(model: HandModel, pair: GraspPlan, finger: int, mix, tracker: PathTracker,
                     elbow: int, obs, origin: np.ndarray, gains: Gains, kp: float, kd: float
                     ) -> np.ndarray | None:
    """Torques while ``pair`` holds the object at ``origin`` and ``finger`` follows a path."""
    zero = np.zeros(3)
    acc, w_O = object_wrench(model, gains, obs.pose, obs.twist, (origin, zero, zero))
    R = rotation(obs.pose[2])
    blend = blended_forces(mix, w_O, R)
    if blend is None:
        return None
    force, normal = blend
    tau = np.zeros(6)
    for k, j in enumerate(pair.fingers):
        qdd = follow_qdd(model, j, obs.q, obs.qd, pair.tips_O[k], acc, obs.twist[2], R)
        tau[2 * j:2 * j + 2] = push_torque(model, j, obs.q, obs.qd, qdd, force[j], normal[j])
    qdd = tracker.qdd(model, finger, elbow, obs, R, kp, kd)
    tau[2 * finger:2 * finger + 2] = push_torque(model, finger, obs.q, obs.qd, qdd,
                                                 force[finger],
                                                 normal.get(finger, np.zeros(2)))
    return tau


def landed(model: HandModel, finger: int, face: Face, coord: float, obs, tol_m: float
           ) -> str | None:
    """None when ``finger`` touches ``face`` within ``tol_m`` of ``coord``, else what is off."""
    gap, at = model.surface_gap(finger, face, obs.pose, obs.q)
    if abs(gap) <= tol_m and abs(at - coord) <= tol_m:
        return None
    return f"finger {finger} {gap * 1e3:.1f} mm off {face.name.lower()} at {at:+.3f} m"


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
        self.times = phase_times(duration_s, PHASES)

    @property
    def result(self) -> Contacts:
        """The contact configuration the flip aims for."""
        face = OPPOSITE[self.contacts.posture.faces[self.finger]]
        return self.contacts.moved(self.finger, coord=self.coord, face=face)

    def start(self, obs) -> str | None:
        model, c, i = self.model, self.contacts, self.finger
        if not all(c.active):
            return "every finger must be in contact before a flip"
        plans = pair_holds(model, c, i, obs, self.gains)
        if isinstance(plans, str):
            return plans
        self.full, self.pair = plans
        self.contacts = model.measured(c, obs.pose, obs.q)
        self.elbow = 1 if obs.q[2 * i + 1] >= 0 else -1
        self.origin = obs.pose.copy()
        k = self.full.fingers.index(i)
        found = self._landing(obs, self.full.tips_O[k], c.posture.faces[i])
        if found is None:
            return f"no reachable landing on the other face holds the object for finger {i}"
        self.coord, self.tracker = found
        self.loaded: GraspPlan | None = None
        return None

    def _landing(self, obs, tip_O: np.ndarray, face: Face, step_m: float = 0.005
                 ) -> tuple[float, PathTracker] | None:
        """The landing coordinate and its path, nearest the present coordinate first."""
        model, i = self.model, self.finger
        new_face = OPPOSITE[face]
        here = self.contacts.coords[i]
        n = int((model.shape.half_extent(new_face) - 2 * model.tip_radius) // step_m)
        R = rotation(obs.pose[2])
        span = landing_span(model, self.contacts, i, new_face, self.gains)
        if span is None:
            return None
        lo, hi = span[0] - SPAN_TOL_M, span[1] + SPAN_TOL_M
        for coord in sorted((k * step_m for k in range(-n, n + 1)), key=lambda c: abs(c - here)):
            if not lo <= coord <= hi:
                continue
            tracker = PathTracker(self._path(tip_O, face, coord), self.times["travel"][0],
                                  self.times["touch"][1])
            if tracker.reachable(model, i, self.elbow, obs.pose, R) and strict_hold(
                    model, self.contacts.moved(i, coord=coord, face=new_face), self.gains):
                return coord, tracker
        return None

    def _path(self, tip_O: np.ndarray, face: Face, coord: float) -> list[np.ndarray]:
        """Tip-centre waypoints (object frame): lift, round the end nearer the base, touch."""
        shape, r = self.model.shape, self.model.tip_radius
        hx, hz = shape.length_m / 2, shape.width_m / 2
        gap = r + self.clearance
        new_face = OPPOSITE[face]
        inward, along = face_axes(face)
        base_x = self.model.fingers[self.finger].base_x
        R = rotation(self.origin[2])
        ends_x = [self.origin[0] + (R @ (e * hx * along))[0] for e in (-1, 1)]
        left_end = abs(ends_x[0] - base_x) <= abs(ends_x[1] - base_x)
        via = Face.LEFT if left_end else Face.RIGHT
        # counter-clockwise when the end to pass is the next face counter-clockwise of ours
        ccw = {Face.TOP: Face.LEFT, Face.LEFT: Face.BOTTOM, Face.BOTTOM: Face.RIGHT,
               Face.RIGHT: Face.TOP}
        ring = route_round(hx, hz, tip_O - self.clearance * inward, face, new_face,
                           hover(hx, hz, new_face, coord, gap), gap,
                           direction=1 if ccw[face] == via else -1)
        return [tip_O, *ring, hover(hx, hz, new_face, coord, r - self.press)]

    def achieved(self, obs, tol_m: float = 0.003) -> str | None:
        """The tip on the new face, within ``tol_m`` of the landing."""
        face = self.result.posture.faces[self.finger]
        return landed(self.model, self.finger, face, self.coord, obs, tol_m)

    def torques(self, obs) -> np.ndarray | None:
        t = obs.t
        un0, un1 = self.times["unload"]
        ld0, ld1 = self.times["load"]
        if t < un1:  # hand the flipping finger's load to the pair
            s = (t - un0) / (un1 - un0)
            mix = [(self.full, 1 - s), (self.pair, s)]
        elif t < ld0:
            mix = [(self.pair, 1.0)]
        else:
            if self.loaded is None:
                self.loaded = GraspPlan.from_state(self.model, self.result, obs.pose, obs.q,
                                                   self.gains)
            s = min(1.0, (t - ld0) / (ld1 - ld0))
            mix = [(self.pair, 1 - s), (self.loaded, s)]
        return handover_torques(self.model, self.pair, self.finger, mix, self.tracker,
                                self.elbow, obs, self.origin, self.gains, self.kp, self.kd)

