"""Release and land (cube, paper section IV-D): a flip split into its two halves.

Release hands one finger's load to the other two (on two different faces whose forces hold
the object: opposite ones, or adjacent ones of a cube, ``flip.pair_holds``), then lifts the tip
clear of its face. Land carries a free tip round the object, outside it, to the
nearest place on another face (the second half of a flip, which puts a finger on a new side)
where the three fingers then hold the object with a squeeze strictly inside the friction cones,
touches down and hands part of the load back. The object is held at its start pose throughout.

Landing on the face the finger left would undo the release: its nearest place is the one the
tip was just lifted from, so no sequence of releases and lands could change the posture, and
goals that only another posture holds (a quarter turn of the cube) would be out of reach.

Land with ``other_elbow`` puts the finger down with its elbow on the other side of its tip
(any face, the one it left too). A two-link finger changes its elbow only through the straight
finger, so the way there is planned in the finger's joint space round the object
(``joint_path``), as a flip's is. A finger's elbow decides which way the object can turn on the
others: the elbow beside the object's lower edge is where its links meet the object first.
"""

from __future__ import annotations

import numpy as np

from inhand_exp.config import PrimitivesConfig
from inhand_exp.control.flip import (
    AIR_M,
    handover_torques,
    ik_clear,
    landed,
    pair_holds,
    phase_times,
)
from inhand_exp.control.grasp import Contacts, Face, face_axes, rotation
from inhand_exp.control.hand import HandModel
from inhand_exp.control.handover import PathTracker, hover, route_round
from inhand_exp.control.joint_path import FreeSpace, JointPath, arrival_times, plan_joint_path
from inhand_exp.control.repose import GraspPlan, strict_hold

RELEASE_PHASES = {"unload": 0.35, "lift": 0.35}  # the rest holds still
LAND_PHASES = {"travel": 0.5, "touch": 0.15, "load": 0.15}


class Release:
    """Primitive: lift ``finger`` off the object while the other two hold it, ``clearance_m``
    (``gains.release_lift_m`` by default) off its face."""

    def __init__(self, model: HandModel, contacts: Contacts, finger: int, duration_s: float,
                 gains: PrimitivesConfig | None = None, clearance_m: float | None = None,
                 kp_joint: float = 900.0, kd_joint: float = 60.0):
        self.model, self.contacts, self.finger = model, contacts, finger
        self.duration_s, self.gains = duration_s, gains or PrimitivesConfig()
        self.clearance = self.gains.release_lift_m if clearance_m is None else clearance_m
        self.kp, self.kd = kp_joint, kd_joint
        self.times = phase_times(duration_s, RELEASE_PHASES)

    @property
    def result(self) -> Contacts:
        return self.contacts.moved(self.finger, active=False)

    def start(self, obs) -> str | None:
        i = self.finger
        if not self.contacts.active[i]:
            return f"finger {i} is not in contact"
        plans = pair_holds(self.model, self.contacts, i, obs, self.gains)
        if isinstance(plans, str):
            return plans
        self.full, self.pair = plans
        k = self.full.fingers.index(i)
        inward, _ = face_axes(self.contacts.posture.faces[i])
        tip = self.full.tips_O[k]
        self.tracker = PathTracker([tip, tip - self.clearance * inward], *self.times["lift"])
        self.elbow = 1 if obs.q[2 * i + 1] >= 0 else -1
        self.origin = obs.pose.copy()
        if not self.tracker.reachable(self.model, i, self.elbow, obs.pose, rotation(obs.pose[2])):
            return f"finger {i} cannot lift off its face"
        return None

    def achieved(self, obs) -> str | None:
        """The tip at least half the clearance off its face."""
        face = self.contacts.posture.faces[self.finger]
        gap, _ = self.model.surface_gap(self.finger, face, obs.pose, obs.q)
        if gap >= self.clearance / 2:
            return None
        return f"finger {self.finger} only {gap * 1e3:.1f} mm off its face"

    def torques(self, obs) -> np.ndarray | None:
        un0, un1 = self.times["unload"]
        s = min(1.0, max(0.0, (obs.t - un0) / (un1 - un0)))
        mix = [(self.full, 1 - s), (self.pair, s)]
        return handover_torques(self.model, self.pair, self.finger, mix, self.tracker,
                                self.elbow, obs, self.origin, self.gains, self.kp, self.kd)


class Land:
    """Primitive: put the free ``finger`` down on another face than the one it left.

    Candidates are every coordinate (5 mm apart) of the other faces; the nearest by path
    length whose grasp admits a strict squeeze and whose path is reachable wins.
    ``other_elbow``: candidates on every face, touched with the elbow on the other side,
    nearest first to the tip's mirror image about the finger's base (``_other_elbow_places``);
    the first of ``max_plans`` whose joint-space way is clear wins.
    """

    def __init__(self, model: HandModel, contacts: Contacts, finger: int, duration_s: float,
                 gains: PrimitivesConfig | None = None, clearance_m: float = 0.02,
                 press_m: float = 0.001, kp_joint: float = 900.0, kd_joint: float = 60.0,
                 step_m: float = 0.005, other_elbow: bool = False, max_plans: int = 6,
                 air_m: float = AIR_M):
        self.model, self.contacts, self.finger = model, contacts, finger
        self.duration_s, self.gains = duration_s, gains or PrimitivesConfig()
        self.clearance, self.press, self.step = clearance_m, press_m, step_m
        self.kp, self.kd = kp_joint, kd_joint
        self.other_elbow, self.max_plans, self.air = other_elbow, max_plans, air_m
        self.times = phase_times(duration_s, LAND_PHASES)

    @property
    def result(self) -> Contacts:
        return self.contacts.moved(self.finger, coord=self.coord, face=self.face, active=True)

    def start(self, obs) -> str | None:
        model, i = self.model, self.finger
        if self.contacts.active[i]:
            return f"finger {i} is already in contact"
        plans = pair_holds(model, self.contacts, i, obs, self.gains)
        if isinstance(plans, str):
            return plans
        _, self.pair = plans
        self.elbow = 1 if obs.q[2 * i + 1] >= 0 else -1
        self.origin = obs.pose.copy()
        R = rotation(obs.pose[2])
        if self.other_elbow:
            return self._start_other_elbow(obs, R)
        tip_O = R.T @ (model.fingers[i].tip(obs.q[2 * i:2 * i + 2]) - obs.pose[:2])
        for _, face, coord, path in self._candidates(tip_O):
            if not strict_hold(model, self.contacts.moved(i, coord=coord, face=face,
                                                          active=True), self.gains, firm=True):
                continue
            tracker = PathTracker(path, self.times["travel"][0], self.times["touch"][1])
            if tracker.reachable(model, i, self.elbow, obs.pose, R):
                self.face, self.coord, self.tracker = face, coord, tracker
                self.loaded: GraspPlan | None = None
                return None
        return f"no reachable landing holds the object for finger {i}"

    def _start_other_elbow(self, obs, R: np.ndarray) -> str | None:
        """``start`` with ``other_elbow``: the first place (``_other_elbow_places``) that the
        finger touches with the other elbow and its links clear, whose grasp holds firmly and
        whose hover its free joint space reaches from where it is, with that way planned."""
        model, i, pose, r = self.model, self.finger, obs.pose, self.model.tip_radius
        hx, hz = model.shape.half_x, model.shape.half_z
        elbow = -self.elbow
        space = FreeSpace(model, i, pose, self.air)
        q0 = obs.q[2 * i:2 * i + 2].copy()
        tries = 0
        for face, coord in self._other_elbow_places(obs, R):
            q_touch = ik_clear(model, i, hover(hx, hz, face, coord, r - self.press), pose, R,
                               model.clearance, prefer=elbow)
            if q_touch is None or (1 if q_touch[1] >= 0 else -1) != elbow:
                continue
            q_hover = ik_clear(model, i, hover(hx, hz, face, coord, r + self.clearance), pose,
                               R, model.clearance, prefer=elbow)
            if q_hover is None or (1 if q_hover[1] >= 0 else -1) != elbow \
                    or not space.ok(q_hover) or not strict_hold(
                        model, self.contacts.moved(i, coord=coord, face=face, active=True),
                        self.gains, firm=True):
                continue
            tries += 1
            way = plan_joint_path(space, q0, q_hover)
            if way is not None:
                t0, t1 = self.times["travel"]
                self.face, self.coord = face, coord
                self.tracker = JointPath([*way, q_touch], [*arrival_times(way, t0, t1, 0.5),
                                                           self.times["touch"][1]])
                self.loaded = None
                return None
            if tries >= self.max_plans:
                break
        return f"no landing with the other elbow has a clear way for finger {i}"

    def _other_elbow_places(self, obs, R: np.ndarray) -> list[tuple[Face, float]]:
        """Every (face, coordinate), nearest first to the tip's mirror image: where the tip
        would be with the finger's joints mirrored about the vertical through its base, the
        same reach with the elbow on the other side."""
        model, i, pose = self.model, self.finger, obs.pose
        r, hx, hz = model.tip_radius, model.shape.half_x, model.shape.half_z
        f = model.fingers[i]
        mirror = f.tip(obs.q[2 * i:2 * i + 2]).copy()
        mirror[0] = 2 * f.base_x - mirror[0]
        mirror_O = R.T @ (mirror - pose[:2])
        places = []
        for face in Face:
            n = int((model.shape.half_extent(face) - 2 * r) // self.step)
            for k in range(-n, n + 1):
                above = hover(hx, hz, face, k * self.step, r + self.clearance)
                places.append((float(np.linalg.norm(above - mirror_O)), face, k * self.step))
        places.sort(key=lambda c: c[0])
        return [(face, coord) for _, face, coord in places]

    def _candidates(self, tip_O: np.ndarray):
        """(path length, face, coordinate, path) for every landing off the face the finger
        left, shortest first."""
        shape, r = self.model.shape, self.model.tip_radius
        hx, hz = shape.half_x, shape.half_z
        gap = r + self.clearance
        # the face the free tip is off: the one whose outward distance is largest
        here = max(Face, key=lambda f: float(-face_axes(f)[0] @ tip_O) - shape.depth(f))
        left = self.contacts.posture.faces[self.finger]  # the face it was released from
        out = []
        for face in (f for f in Face if f != left):
            n = int((shape.half_extent(face) - 2 * r) // self.step)
            for k in range(-n, n + 1):
                coord = k * self.step
                path = [tip_O, *route_round(hx, hz, tip_O, here, face,
                                            hover(hx, hz, face, coord, gap), gap)[1:],
                        hover(hx, hz, face, coord, r - self.press)]
                length = sum(float(np.linalg.norm(b - a)) for a, b in zip(path, path[1:],
                                                                         strict=False))
                out.append((length, face, coord, path))
        out.sort(key=lambda c: c[0])
        return out

    def achieved(self, obs, tol_m: float = 0.003) -> str | None:
        return landed(self.model, self.finger, self.face, self.coord, obs, tol_m)

    def torques(self, obs) -> np.ndarray | None:
        ld0, ld1 = self.times["load"]
        if obs.t < ld0:
            mix = [(self.pair, 1.0)]
        else:
            if self.loaded is None:
                self.loaded = GraspPlan.from_state(self.model, self.result, obs.pose, obs.q,
                                                   self.gains)
            s = min(1.0, (obs.t - ld0) / (ld1 - ld0))
            mix = [(self.pair, 1 - s), (self.loaded, s)]
        return handover_torques(self.model, self.pair, self.finger, mix, self.tracker,
                                self.elbow, obs, self.origin, self.gains, self.kp, self.kd)
