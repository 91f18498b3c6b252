"""The task of the paper (section IV), in the manner of dm_control's ``Task``: bring the object
from X0 to Xg and never drop it.

``GoalTask`` owns what every environment of the task shares, whatever its action is (a
primitive for the mid level, six torques end to end):

- the episode's pair: fixed goals taken in order (evaluation), or a fresh training pair drawn
  from the ``goals`` group (or from a group of ``goals.train_groups``);
- the reset: the world put at X0 with the fingertips on the simulated object's surface;
- success (|dx|, |dz| < tol_m and |dtheta| < tol_rad, from the simulated pose), the drop (given
  by the caller, judged from PyBullet's contacts), the reward and the time limit: at most
  ``max_actions`` actions (the mid level: ``task.max_actions``) or ``time_limit_s`` simulated
  seconds (end to end: ``task.time_limit_s``).

An environment is then a thin sequencer: reset the task, act, ``judge``, observe.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from inhand_exp.config import SearchConfig
from inhand_exp.control.hand import GeometryError
from inhand_exp.task.goals import (
    FLIP_FINGERS,
    PRESS_M,
    GoalPair,
    Start,
    reach_fingers,
    sample_pair,
    start_of,
)
from inhand_exp.task.graph import cached_graph
from inhand_exp.task.route import RouteTime
from inhand_exp.task.rules import reached, reward, to_go
from inhand_exp.task.scene import Scene


@dataclass(frozen=True)
class Verdict:
    """How the last action left the episode."""

    success: bool
    dropped: bool
    terminated: bool  # success or drop
    truncated: bool  # the time limit, without success or drop
    reward: float


class GoalTask:
    """Episodes of one scene: ``reset`` starts the next one, ``judge`` scores each action.

    ``goals``: the pairs to play in order (evaluation); None draws training pairs from
    ``groups`` with ``hard_posture`` (see ``goals.sample_pair``). ``once``: play each of
    ``goals`` once, after which ``reset`` returns False. An episode ends after ``max_actions``
    actions or ``time_limit_s`` simulated seconds, whichever comes first (None: no such limit).
    ``pool`` > 0: keep the first ``pool`` training pairs drawn and, once there are that many,
    draw episodes from them uniformly (drawing a pair takes about 0.2 s, far longer than an
    end-to-end episode that drops the object at once). ``start``: the pose and grasp every
    training pair starts from (``goals.x0``), or None. ``fingers``: see ``goals.sample_pair``
    (None: no pair is left out). ``route``: the route potential of ``task.reward_route``.
    """

    def __init__(self, scene: Scene, groups: tuple[str, ...] = ("medium",),
                 hard_posture: str = "other", goals: list[GoalPair] | None = None,
                 once: bool = False, max_actions: int | None = None,
                 time_limit_s: float | None = None, pool: int = 0,
                 start: Start | None = None,
                 fingers: tuple[int, ...] | None = FLIP_FINGERS,
                 route: RouteTime | None = None):
        self.scene, self.rules = scene, scene.rules
        self.route = route
        self.start, self.fingers = start, fingers
        self.groups, self.hard_posture = tuple(groups), hard_posture
        self.goals, self.once = goals, once and goals is not None
        self.max_actions, self.time_limit_s = max_actions, time_limit_s
        self.pool_size, self.pool = pool, []
        self.episode = 0  # episodes started
        self.pair: GoalPair | None = None
        self.goal = np.zeros(3)
        self.n_actions, self.n_invalid, self.sim_time = 0, 0, 0.0
        self.success = self.dropped = False

    @classmethod
    def from_config(cls, scene: Scene, cfg, end_to_end: bool = False, **kwargs) -> GoalTask:
        """The task of the ``goals`` config group for ``scene``; its time limit is
        ``task.max_actions`` mid-level actions, or ``task.time_limit_s`` ``end_to_end``."""
        goals = cfg["goals"]
        limit = ({"time_limit_s": scene.rules.time_limit_s} if end_to_end
                 else {"max_actions": scene.rules.max_actions})
        route = None
        if scene.rules.reward_route > 0 and not end_to_end:
            graph = cached_graph(cfg, SearchConfig(cache_dir=scene.rules.route_cache_dir))
            route = RouteTime(graph, scene.model,
                              scene.rules.route_cap_s)
        return cls(scene, tuple(goals["train_groups"]) or (goals["name"],),
                   goals["hard_goal_posture"], **limit, route=route,
                   start=start_of(scene.model, goals) if kwargs.get("goals") is None else None,
                   fingers=reach_fingers(scene.model, cfg), **kwargs)

    @property
    def exhausted(self) -> bool:
        """Every pair of ``goals`` has been played (``once`` only)."""
        return self.once and self.episode >= len(self.goals)

    def next_pair(self, rng: np.random.Generator) -> GoalPair:
        if self.goals is not None:
            return self.goals[self.episode % len(self.goals)]
        if self.pool_size and len(self.pool) >= self.pool_size:
            return self.pool[int(rng.integers(len(self.pool)))]
        group = self.groups[int(rng.integers(len(self.groups)))] if len(self.groups) > 1 \
            else self.groups[0]
        s = self.scene
        return sample_pair(s.model, group, rng, s.workspace, self.hard_posture,
                           (s.rules.success_tol_m, s.rules.success_tol_rad), start=self.start,
                           fingers=self.fingers)

    def reset(self, rng: np.random.Generator) -> bool:
        """Start the next episode: the object at X0, the fingers on its simulated surface, at
        rest. False (and nothing simulated) once ``goals`` are exhausted.

        Pairs are drawn on the nominal object; under a perturbation (a thicker pole) the same
        contacts may not fit the simulated one with the links clear. A training draw is then
        drawn again; a pair of ``goals`` is refused with ``GeometryError`` naming it.
        """
        if self.exhausted:
            return False
        s = self.scene
        for tries in range(1, 101):
            pair = self.next_pair(rng)
            try:  # the grasp is drawn on the nominal object; the fingers touch the simulated one
                q = s.true_model.grasp_q(pair.contacts, pair.x0, PRESS_M)
                break
            except GeometryError as err:
                if self.goals is not None or tries == 100:
                    raise GeometryError(f"goal pair {self.episode}: the simulated object cannot "
                                        f"be held at X0 with its grasp: {err}") from None
        self.episode += 1
        if self.goals is None and len(self.pool) < self.pool_size:
            self.pool.append(pair)
        self.pair, self.goal = pair, pair.xg.copy()
        s.world.reset(pair.x0, q)
        self.n_actions, self.n_invalid, self.sim_time = 0, 0, 0.0
        self.success = self.dropped = False
        return True

    def route_to_go(self) -> float | None:
        """The graph's route time from the simulated state to the goal (the route potential),
        or None without ``route``."""
        if self.route is None:
            return None
        w = self.scene.world
        return self.route(w.joint_q(), w.object_pose(), self.goal)

    def to_go(self, pose: np.ndarray) -> float:
        """Distance of ``pose`` to the goal, in tolerances (the progress potential)."""
        return to_go(pose, self.goal, self.rules)

    def judge(self, dropped: bool, sim_time_s: float, valid: bool = True,
              useful_flip: bool = False, before: float | None = None,
              route_before: float | None = None) -> Verdict:
        """Score one action that took ``sim_time_s`` and ended with ``dropped`` (the object no
        longer held, as the simulator says). Success is read from the simulated pose.
        ``before``: ``to_go`` before the action, for the progress shaping; ``route_before``:
        ``route_to_go`` before it, for the route shaping (none on a drop: the grasp is gone).
        With ``task.reward_flip_needed``, a useful flip is paid only where the pair needs one."""
        self.n_actions += 1
        self.n_invalid += not valid
        self.sim_time += sim_time_s
        pose = self.scene.world.object_pose()
        self.dropped = bool(dropped)
        self.success = not self.dropped and reached(pose, self.goal, self.rules)
        terminated = self.success or self.dropped
        out_of_time = (self.max_actions is not None and self.n_actions >= self.max_actions) or (
            self.time_limit_s is not None and self.sim_time >= self.time_limit_s - 1e-9)
        progress = 0.0 if before is None else before - self.to_go(pose)
        route = 0.0  # the goal's potential is 0; a drop pays none (its contacts mean nothing)
        if route_before is not None and not self.dropped:
            route = route_before - (0.0 if self.success else self.route_to_go())
        if useful_flip and self.rules.reward_flip_needed and not self.pair.needs_flip:
            useful_flip = False
        r = reward(self.rules, valid=valid, success=self.success, useful_flip=useful_flip,
                   progress=progress, route=route)
        return Verdict(self.success, self.dropped, terminated, not terminated and out_of_time, r)
