"""Run one primitive to its end on a world, torque every physics step, and report the outcome."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from inhand_exp.sim.world import state_problem


@dataclass(frozen=True)
class Observation:
    """What the controllers see: joints exactly, the object pose possibly with noise.

    ``plans``: a cache of the grasp plans made from this very observation (see
    ``repose.plan_for``), so that primitives planned on it together (the feasibility filter
    plans every action) build each plan once; None disables it.
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


class WorldLike(Protocol):
    dt: float
    time_s: float

    def object_state(self) -> tuple[np.ndarray, np.ndarray]: ...
    def joint_state(self) -> tuple[np.ndarray, np.ndarray]: ...
    def step(self, tau: np.ndarray) -> None: ...
    def grasp_lost(self) -> str | None: ...


StateCheck = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], "str | None"]


@dataclass(frozen=True)
class Outcome:
    """How a primitive ended: ``reason`` is done, infeasible, lost_contact, unstable, timeout
    (the time ran out before the goal was reached)."""

    ok: bool
    reason: str
    detail: str
    sim_time_s: float
    steps: int


def execute(world: WorldLike, primitive: Primitive, pose_offset: np.ndarray | None = None,
            check_every: int = 4, drop_grace_s: float = 0.05,
            state_check: StateCheck = state_problem, started: bool = False) -> Outcome:
    """Drive ``primitive`` for its duration; stop early on infeasibility, a drop or instability.

    ``pose_offset`` is the observation error on the object pose (noise drawn by the caller, held
    for the primitive). Every ``check_every`` steps the simulated state is checked with
    ``state_check`` and the grasp from PyBullet's contacts; a loss lasting ``drop_grace_s`` is a
    drop. ``started``: the primitive was already planned (``start`` accepted) on the current
    state, as the feasibility filter does, so it is not planned again.
    """
    offset = np.zeros(3) if pose_offset is None else pose_offset
    n = round(primitive.duration_s / world.dt)
    lost_since: float | None = None

    def read() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        pose, twist = world.object_state()
        q, qd = world.joint_state()
        return pose, twist, q, qd

    pose, twist, q, qd = read()
    why = None if started else primitive.start(Observation(q, qd, pose + offset, twist, 0.0))
    if why is not None:
        return Outcome(False, "infeasible", why, 0.0, 0)
    for k in range(n):
        if k:
            pose, twist, q, qd = read()
            if k % check_every == 0:  # the state after step k - 1
                bad = state_check(pose, twist, q, qd)
                if bad is not None:
                    return Outcome(False, "unstable", bad, k * world.dt, k)
        tau = primitive.torques(Observation(q, qd, pose + offset, twist, k * world.dt))
        if tau is None:
            return Outcome(False, "infeasible", "no contact forces inside the friction cones",
                           k * world.dt, k)
        world.step(tau)
        if (k + 1) % check_every:
            continue
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
    missing = primitive.achieved(Observation(q, qd, pose + offset, twist, n * world.dt))
    if missing is not None:
        return Outcome(False, "timeout", missing, n * world.dt, n)
    return Outcome(True, "done", "", n * world.dt, n)
