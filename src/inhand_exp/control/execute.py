"""Run one primitive to its end on a world, torques every control period, and report the outcome."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from inhand_exp.sim.world import NonFiniteTorque, state_problem


@dataclass(frozen=True)
class Observation:
    """What the controllers see: joints exactly, the object pose possibly with noise.

    ``plans``: a cache of the grasp plans made from this very observation (see
    ``repose.plan_for``), and of the tips' gaps to their faces (``repose.face_gaps``), so that
    primitives planned on it together (the feasibility filter plans every action) work each
    out once; None disables it.
    """

    q: np.ndarray
    qd: np.ndarray
    pose: np.ndarray
    twist: np.ndarray
    t: float  # time since the primitive started (s)
    plans: dict[Any, Any] | None = field(default=None, compare=False)


class Primitive(Protocol):
    """A low-level controller: planned at the first observation, then torques every step."""

    duration_s: float

    def start(self, obs: Observation) -> str | None:
        """Plan from the first observation; a reason string if the primitive is infeasible."""

    def torques(self, obs: Observation) -> np.ndarray | None:
        """Joint torques (6,) for this step, or None if the forces became infeasible."""

    def achieved(self, obs: Observation) -> str | None:
        """At the end: None if the goal is reached in ``obs``, else what is missing."""

    # Optional: ``settled(obs) -> bool``, True when the primitive may end now because its goal
    # is reached and nothing moves (see ``execute``'s ``settle_early``).


class WorldLike(Protocol):
    dt: float
    time_s: float

    def object_state(self) -> tuple[np.ndarray, np.ndarray]: ...
    def joint_state(self) -> tuple[np.ndarray, np.ndarray]: ...
    def step(self, tau: np.ndarray) -> None: ...
    def grasp_lost(self) -> str | None: ...
    def hand_contact_points(self) -> list[tuple[str, np.ndarray]]: ...


StateCheck = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], "str | None"]

DROP_GRACE_S = 0.05  # a grasp lost for this long (s) is a drop

# How every primitive can end. A drop is lost_contact or unstable.
REASONS = ("done", "infeasible", "lost_contact", "unstable", "timeout", "link_contact")


@dataclass(frozen=True)
class Outcome:
    """How a primitive ended: ``reason`` is one of ``REASONS``:

    - done: the primitive's goal reached, only fingertips touching the object;
    - infeasible: refused at the start, or its force plan failed on the way (the hand then
      held its joints still for ``settle_s`` and the object was still held);
    - lost_contact: the object was no longer held (PyBullet's contacts), or it fell or slid
      more than ``fall_m`` from where the primitive was taking it: a drop;
    - unstable: the simulation blew up (NaN, runaway speeds): a drop;
    - timeout: the time ran out before the goal was reached;
    - link_contact: a link or the palm touched the object on the way (``detail`` names them);
      ``reached`` says whether the goal was reached all the same, and ``reach_m`` how far
      from the object's centre along its long axis they touched it, at most (m, in the frame
      of the observed pose): a point past the model's end shows the object longer.
    """

    ok: bool
    reason: str
    detail: str
    sim_time_s: float
    steps: int
    reached: bool = False
    reach_m: float = 0.0

    @property
    def dropped(self) -> bool:
        return self.reason in ("lost_contact", "unstable")


def _off_course(pose: np.ndarray, start: np.ndarray, delta: np.ndarray) -> float:
    """How far (m) ``pose`` is from the straight path ``start`` -> ``start + delta`` in x-z."""
    dx, dz = float(delta[0]), float(delta[1])
    ex, ez = float(pose[0]) - float(start[0]), float(pose[1]) - float(start[1])
    n = dx * dx + dz * dz
    s = 0.0 if n == 0.0 else min(1.0, max(0.0, (ex * dx + ez * dz) / n))
    return math.hypot(ex - s * dx, ez - s * dz)


def along_axis(point: np.ndarray, pose: np.ndarray) -> float:
    """How far world ``point`` (x, z) lies from the centre of an object at ``pose`` along its
    long axis (the object frame's z), either way (m)."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    dx, dz = float(point[0]) - float(pose[0]), float(point[1]) - float(pose[1])
    return abs(-s * dx + c * dz)


def joint_hold(q_ref: np.ndarray, q: np.ndarray, qd: np.ndarray, kp: float = 40.0,
               kd: float = 2.0) -> np.ndarray:
    """A safe stop: a joint PD holding the fingers where they were (N m)."""
    return kp * (q_ref - q) - kd * qd


def execute(world: WorldLike, primitive: Primitive, pose_offset: np.ndarray | None = None,
            check_every: int = 4, drop_grace_s: float = DROP_GRACE_S,
            state_check: StateCheck = state_problem, started: bool = False,
            fall_m: float = 0.02, settle_s: float = 0.25, settle_early: bool = False) -> Outcome:
    """Drive ``primitive`` for its duration; stop early on infeasibility, a drop or instability.

    ``pose_offset`` is the observation error on the object pose (noise drawn by the caller, held
    for the primitive). Every ``check_every`` steps the simulated state is checked with
    ``state_check``, the grasp from PyBullet's contacts (a loss lasting ``drop_grace_s`` is a
    drop), how far the object is from the path the primitive moves it along (more than
    ``fall_m`` is a drop, wherever the fingertips are) and whether any part of the hand but the
    fingertips touches it. ``started``: the primitive was already planned (``start`` accepted)
    on the current state, as the feasibility filter does, so it is not planned again. When the
    force plan fails on the way, the hand holds its joints for ``settle_s`` and the object is
    judged again: a drop if it is not held then. ``settle_early``: a primitive with a
    ``settled`` test that passes at a check ends there, judged as at the end of its duration
    (the rest of its time would only hold the object still where it already is).
    """
    offset = np.zeros(3) if pose_offset is None else pose_offset
    n = round(primitive.duration_s / world.dt)
    settled = getattr(primitive, "settled", None) if settle_early else None
    lost_since: float | None = None
    touched: set[str] = set()
    reach = 0.0  # the farthest along the long axis a link or the palm touched the object

    def read() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        pose, twist = world.object_state()
        q, qd = world.joint_state()
        return pose, twist, q, qd

    pose, twist, q, qd = read()
    why = None if started else primitive.start(Observation(q, qd, pose + offset, twist, 0.0))
    if why is not None:
        return Outcome(False, "infeasible", why, 0.0, 0)
    start = pose.copy()
    goal = getattr(primitive, "goal", None)
    origin = getattr(primitive, "origin", None)
    delta = np.zeros(3) if goal is None or origin is None else goal - origin

    def fell(pose: np.ndarray) -> str | None:
        off = _off_course(pose, start, delta)
        return None if off <= fall_m else f"object {off * 100:.1f} cm off its course"

    for k in range(n):
        if k:
            pose, twist, q, qd = read()
            if k % check_every == 0:  # the state after step k - 1
                bad = state_check(pose, twist, q, qd)
                if bad is not None:
                    return Outcome(False, "unstable", bad, k * world.dt, k)
                lost = fell(pose)
                if lost is not None:
                    return Outcome(False, "lost_contact", lost, k * world.dt, k)
                if settled is not None and lost_since is None and settled(
                        Observation(q, qd, pose + offset, twist, k * world.dt)):
                    n = k
                    break
        tau = primitive.torques(Observation(q, qd, pose + offset, twist, k * world.dt))
        if tau is None:
            return _safe_stop(world, q, k, fell, state_check, settle_s, check_every)
        try:
            world.step(tau)
        except NonFiniteTorque as err:  # a controller fault: the world refused it
            return Outcome(False, "unstable", str(err), k * world.dt, k)
        if (k + 1) % check_every:
            continue
        for name, at in world.hand_contact_points():
            touched.add(name)
            reach = max(reach, along_axis(at, pose + offset))
        lost = world.grasp_lost()
        if lost is None:
            lost_since = None
        elif lost_since is None:
            lost_since = k * world.dt
        elif (k + 1) * world.dt - lost_since >= drop_grace_s:
            return Outcome(False, "lost_contact", lost, (k + 1) * world.dt, k + 1)
    pose, twist, q, qd = read()
    bad = state_check(pose, twist, q, qd)
    if bad is not None:
        return Outcome(False, "unstable", bad, n * world.dt, n)
    lost = fell(pose) or (world.grasp_lost() if lost_since is not None else None)
    if lost is not None:
        return Outcome(False, "lost_contact", lost, n * world.dt, n)
    missing = primitive.achieved(Observation(q, qd, pose + offset, twist, n * world.dt))
    if touched:
        return Outcome(False, "link_contact", ", ".join(sorted(touched)) + " touched the object",
                       n * world.dt, n, reached=missing is None, reach_m=reach)
    if missing is not None:
        return Outcome(False, "timeout", missing, n * world.dt, n)
    return Outcome(True, "done", "", n * world.dt, n, reached=True)


def _safe_stop(world: WorldLike, q_ref: np.ndarray, k: int, fell, state_check: StateCheck,
               settle_s: float, check_every: int) -> Outcome:
    """The force plan failed after ``k`` steps: hold the joints, then judge the grasp."""
    m = round(settle_s / world.dt)
    for j in range(m):
        q, qd = world.joint_state()
        world.step(joint_hold(q_ref, q, qd))
        if (j + 1) % check_every == 0:
            pose, twist = world.object_state()
            bad = state_check(pose, twist, q, qd)
            if bad is not None:
                return Outcome(False, "unstable", bad, (k + j + 1) * world.dt, k + j + 1)
    t = (k + m) * world.dt
    lost = world.grasp_lost() or fell(world.object_state()[0])
    if lost is not None:
        return Outcome(False, "lost_contact", f"force plan failed, then {lost}", t, k + m)
    return Outcome(False, "infeasible", "no contact forces inside the friction cones", t, k + m)
