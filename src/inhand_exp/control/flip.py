"""Flip (pole): take one finger off its face, carry it round the end, put it on the other face.

Phases, as fractions of the duration: unload (the flipping finger's share of the contact force
ramps to zero while the other two take the whole load), travel (the finger lifts its tip off
the face, then follows a path planned in its joint space round the object, links and tip clear
of it and above the palm, to hover off the other face: for an upright pole that is under its
lower end, often changing the elbow branch through the straight finger), touch (the tip presses
onto the new face), load (the force distribution is planned again from the measured contacts
and ramps from two contacts to three), settle. The two
fingers that stay must hold the object alone: they must push from opposite faces, and the
two-contact force problem must be feasible. The object is held at its start pose throughout.
"""

from __future__ import annotations

import numpy as np

from inhand_exp.config import PrimitivesConfig
from inhand_exp.control.grasp import (
    Contacts,
    Face,
    face_axes,
    face_shifted,
    rotation,
)
from inhand_exp.control.hand import HandModel
from inhand_exp.control.handover import blended_forces, hover
from inhand_exp.control.joint_path import FreeSpace, JointPath, arrival_times, plan_joint_path
from inhand_exp.control.repose import (
    GraspPlan,
    face_gap,
    follow_qdd,
    found_model,
    landing_span,
    object_wrench,
    plan_for,
    push_torque,
    strict_hold,
)
from inhand_exp.control.sample import elongated

OPPOSITE = {Face.TOP: Face.BOTTOM, Face.BOTTOM: Face.TOP,
            Face.LEFT: Face.RIGHT, Face.RIGHT: Face.LEFT}
SPAN_TOL_M = 1e-5  # landing_span's bounds are trusted this far inside and outside of them
PHASES = {"unload": 0.12, "travel": 0.55, "touch": 0.1, "load": 0.1}  # the rest settles
LIFT_M = 0.02  # how far the tip lifts off the face before its travel, and hovers off the new one
AIR_M = 0.006  # the margin of the travel round the object (links and tip)
PRESS_M = 0.001  # how far inside the new face the tip is aimed when it touches


def phase_times(duration_s: float, phases: dict[str, float]) -> dict[str, tuple[float, float]]:
    """Start and end (s) of each phase from its fraction of the duration."""
    t, times = 0.0, {}
    for name, frac in phases.items():
        times[name] = (t, t + frac * duration_s)
        t += frac * duration_s
    return times


def holds_firmly(model: HandModel, contacts: Contacts, finger: int, face: Face, coord: float,
                 span: tuple[float, float], gains: PrimitivesConfig) -> bool:
    """``strict_hold(..., firm=True)`` of ``finger`` landed at ``coord`` on ``face``, known
    without its LP well inside ``span`` (``landing_span(..., firm=True)``, the coordinates
    where such a landing holds firmly) and asked near its ends."""
    if span[0] + SPAN_TOL_M <= coord <= span[1] - SPAN_TOL_M:
        return True
    return strict_hold(model, contacts.moved(finger, coord=coord, face=face), gains, firm=True)


def pair_holds(model: HandModel, contacts: Contacts, finger: int, obs, gains: PrimitivesConfig
               ) -> tuple[GraspPlan, GraspPlan] | str:
    """Plans with and without ``finger``, or why the other two cannot hold the object alone.

    The two must be on different faces: opposite ones for a pole (a pole with one long side
    bare is dropped), any two for a cube (adjacent faces too: a bottom tip can bear the weight
    while a side tip presses). Their force distribution decides the rest."""
    others = [j for j in range(3) if j != finger]
    if not all(contacts.active[j] for j in others):
        return f"fingers {others} must both be in contact"
    faces = [contacts.posture.faces[j] for j in others]
    if faces[0] == faces[1]:
        return f"fingers {others} are on one face"
    if elongated(model) and faces[0] != OPPOSITE[faces[1]]:
        return f"fingers {others} do not oppose each other"
    full = plan_for(model, contacts, obs, gains)
    pair = plan_for(model, contacts.moved(finger, active=False), obs, gains)
    zero = np.zeros(3)
    _, w_O = object_wrench(model, gains, obs.pose, zero, (obs.pose, zero, zero))
    if pair.squeeze.solve(w_O) is None or (contacts.active[finger]
                                           and full.squeeze.solve(w_O) is None):
        return f"fingers {others} cannot hold the object alone"
    return full, pair


def handover_torques(model: HandModel, pair: GraspPlan, finger: int, mix, tracker,
                     elbow: int, obs, origin: np.ndarray, gains: PrimitivesConfig, kp: float,
                     kd: float) -> np.ndarray | None:
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


def landed(model: HandModel, finger: int, face: Face, coord: float, obs, tol_m: float,
           face_gap: float = 0.0) -> str | None:
    """None when ``finger`` touches ``face`` (found ``face_gap`` off the nominal one) within
    ``tol_m`` of ``coord``, else what is off."""
    gap, at = model.surface_gap(finger, face, obs.pose, obs.q)
    gap -= face_gap
    if abs(gap) <= tol_m and abs(at - coord) <= tol_m:
        return None
    return f"finger {finger} {gap * 1e3:.1f} mm off {face.name.lower()} at {at:+.3f} m"


def ik_clear(model: HandModel, finger: int, point_O: np.ndarray, pose: np.ndarray,
             R: np.ndarray, margin: float, prefer: int | None = None,
             check_pose: np.ndarray | None = None) -> np.ndarray | None:
    """Joint angles of ``finger`` putting its tip centre at ``point_O`` (object frame) with the
    links ``margin`` clear of the object (at ``check_pose`` if given), the elbow branch
    ``prefer`` tried first."""
    f = model.fingers[finger]
    check = pose if check_pose is None else check_pose
    order = (1, -1) if prefer is None or prefer == 1 else (-1, 1)
    for elbow in order:
        qi = f.ik(pose[:2] + R @ point_O, elbow)
        if qi is not None and f.within_limits(qi, 0.05) and \
                model.finger_gap(finger, qi, check) >= margin:
            return qi
    return None


class Flip:
    """Primitive: move ``finger`` to the opposite face.

    It lands at the coordinate nearest its present one where the new grasp admits a squeeze
    strictly inside the friction cones (a grasp that only gravity makes feasible proved fragile
    while the force is handed over), where the finger touches with its links clear and where a
    path in the finger's joint space (``joint_path``) gets it there without touching the object.
    Round the ends the path keeps ``flip_end_margin_m`` more room where such a path exists
    (``end_margin`` says which it took): a pole longer than modelled has its real ends there.
    """

    def __init__(self, model: HandModel, contacts: Contacts, finger: int, duration_s: float,
                 gains: PrimitivesConfig | None = None, clearance_m: float = LIFT_M,
                 press_m: float = PRESS_M, kp_joint: float = 900.0, kd_joint: float = 60.0,
                 max_plans: int = 6,
                 air_m: float = AIR_M):
        self.model, self.contacts, self.finger = model, contacts, finger
        self.duration_s, self.gains = duration_s, gains or PrimitivesConfig()
        self.clearance, self.press = clearance_m, press_m
        self.kp, self.kd = kp_joint, kd_joint
        self.max_plans = max_plans  # landings whose path is searched for, nearest first
        self.air = air_m  # margin of the travel round the object (links and tip)
        self.end_margin = 0.0  # the room round the ends the planned path keeps (set by start)
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
        face = c.posture.faces[i]
        # the faces where the fingertips find them: the new face is where the staying finger
        # on it touches, the old one where this finger does
        self.gap_old = face_gap(model, c, face, obs)
        self.gap_new = face_gap(model, c, OPPOSITE[face], obs, exclude=i)
        found = self._landing(obs, face)
        if found is None:
            return f"no landing on the other face that holds the object has a clear path for " \
                   f"finger {i}"
        self.coord, self.tracker = found
        self.loaded: GraspPlan | None = None
        return None

    def _ik_clear(self, point_O: np.ndarray, pose: np.ndarray, R: np.ndarray,
                  margin: float, prefer: int | None = None,
                  check_pose: np.ndarray | None = None) -> np.ndarray | None:
        return ik_clear(self.model, self.finger, point_O, pose, R, margin, prefer, check_pose)

    def _landing(self, obs, face: Face, step_m: float = 0.005
                 ) -> tuple[float, JointPath] | None:
        """The landing coordinate and the finger's joint path, nearest the present first."""
        model, i = self.model, self.finger
        pose, R = obs.pose, rotation(obs.pose[2])
        self.found = found_model(model, self.contacts, obs)  # the landing is judged on it
        span = landing_span(self.found, self.contacts, i, OPPOSITE[face], self.gains, firm=True)
        if span is None:
            return None
        q0 = obs.q[2 * i:2 * i + 2].copy()
        inward, _ = face_axes(face)
        lift_O = self.full.tips_O[self.full.fingers.index(i)] - self.clearance * inward
        q_lift = self._ik_clear(lift_O, pose, R, model.clearance, prefer=self.elbow)
        if q_lift is None:
            return None
        air = self.air + max(0.0, self.gap_old, self.gap_new)
        # the travel keeps its air to the faces where they were found, if further out; round
        # the ends it keeps flip_end_margin_m more where it can (a pole longer than modelled).
        # The free space with the margin lies inside the one without: a flip is offered when
        # the nominal ends allow it, and only then is the margin tried.
        found = self._path(FreeSpace(model, i, pose, air), pose, q0, q_lift, span, step_m)
        margin = self.gains.flip_end_margin_m
        if found is not None and margin > 0:
            wider = self._path(FreeSpace(model.lengthened(margin), i, pose, air), pose, q0,
                               q_lift, span, step_m)
            if wider is not None:
                found, self.end_margin = wider, margin
        return found

    def _path(self, space: FreeSpace, pose: np.ndarray, q0: np.ndarray, q_lift: np.ndarray,
              span: tuple[float, float], step_m: float) -> tuple[float, JointPath] | None:
        """The landing nearest the finger's present coordinate that holds the object and whose
        hover ``space`` reaches from ``q_lift``, with the joint path from ``q0`` to it."""
        model, i = self.model, self.finger
        if not space.ok(q_lift):
            return None
        shape, r = model.shape, model.tip_radius
        new_face = OPPOSITE[self.contacts.posture.faces[i]]
        here = self.contacts.coords[i]
        n = int((shape.half_extent(new_face) - 2 * r) // step_m)
        R = rotation(pose[2])
        lo, hi = span[0] - SPAN_TOL_M, span[1] + SPAN_TOL_M
        hx, hz = shape.half_x, shape.half_z
        g = self.gap_new
        at_new = face_shifted(pose, face_axes(new_face)[0], g)
        tries = 0
        for coord in sorted((j * step_m for j in range(-n, n + 1)), key=lambda c: abs(c - here)):
            if not lo <= coord <= hi:
                continue
            q_touch = self._ik_clear(hover(hx, hz, new_face, coord, r + g - self.press), pose,
                                     R, model.clearance, check_pose=at_new)
            if q_touch is None:
                continue
            branch = 1 if q_touch[1] >= 0 else -1
            q_hover = self._ik_clear(hover(hx, hz, new_face, coord, r + g + self.clearance),
                                     pose, R, model.clearance, prefer=branch,
                                     check_pose=at_new)
            if q_hover is None or not space.ok(q_hover) or not holds_firmly(
                    self.found, self.contacts, i, new_face, coord, span, self.gains):
                continue
            tries += 1
            way = plan_joint_path(space, q_lift, q_hover)
            if way is not None:
                t_lift = self.times["travel"][0] + 0.1 * (self.times["travel"][1]
                                                           - self.times["travel"][0])
                times = [self.times["travel"][0],
                         *arrival_times(way, t_lift, self.times["travel"][1]),
                         self.times["touch"][1]]
                return coord, JointPath([q0, *way, q_touch], times)
            if tries >= self.max_plans:
                return None
        return None

    def achieved(self, obs, tol_m: float = 0.003) -> str | None:
        """The tip on the new face, within ``tol_m`` of the landing."""
        face = self.result.posture.faces[self.finger]
        return landed(self.model, self.finger, face, self.coord, obs, tol_m, self.gap_new)

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
