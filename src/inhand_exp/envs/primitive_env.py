"""The mid-level TorchRL environment (paper section III-B): one step is one primitive.

Clocks: the policy acts once per primitive; the primitive's torque law runs every control period
(``sim.timestep_s`` x ``sim.control_substeps``) for the primitive's duration, or until it has
settled (``primitives.settle_early``). Observation (paper IV-A): joint angles and
velocities (12), the observed object pose ``X_t`` (3, with uniform noise under ``noise=paper``)
and the goal ``X_g`` (3), then with ``task.route_advice`` the search graph's view of the
observed state (``task.route.RouteAdvice``, 15 floats), then with ``task.posture_advice``
whether the posture can hold the goal (``task.posture_advice.PostureAdvice``, 2 flags);
``action_mask`` says which actions the feasibility filter allows (with ``task.no_undo``, not the
one that undoes the last; with ``task.no_undo_flip``, not the last flip again; with
``task.no_repeat_contact``, not the last action again when it ended touching a link or the palm).
With ``task.touch_finds_length``, a link or the palm touching the object past the model's end
lengthens the model (filter and primitives) to where it touched, until the episode ends.
``success``, ``dropped`` and ``sim_time_s`` are reported beside the observation for evaluation,
with the true object ``pose``, whether the last action was ``valid``, its ``outcome`` (an index
into ``OUTCOMES``), the ``physics_steps`` the world has taken since it was made, the wall
time spent since then in the feasibility filter, in executing primitives and inside
``stepSimulation`` (``wall_s``, 3 values, for benchmarks) and, when
``states_hz`` > 0, the ``states`` snapshots taken during it (see
``envs.snapshots``). None of these is part of the policy's ``observation``.
Filter modes: ``mask`` (only allowed actions may be taken; an episode with none ends), ``penalty``
(the paper: a rejected action costs ``task.reward_invalid`` and does nothing) and ``off`` (every
action is attempted; one its primitive refuses does nothing and costs the same).
"""

from __future__ import annotations

import time

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Binary, Categorical, Unbounded
from torchrl.envs import EnvBase

from inhand_exp.config import SearchConfig
from inhand_exp.control.execute import REASONS, execute
from inhand_exp.envs.snapshots import STATE_WIDTH, Snapshots
from inhand_exp.envs.specs import OBS_DIM, declare_mid_level_specs, idle_output
from inhand_exp.task.actions import action_table, feasibility, make_primitive, undo_actions
from inhand_exp.task.goal_task import GoalTask
from inhand_exp.task.goals import GoalPair
from inhand_exp.task.graph import cached_graph
from inhand_exp.task.posture_advice import PostureAdvice
from inhand_exp.task.route import RouteAdvice
from inhand_exp.task.rules import flip_useful
from inhand_exp.task.scene import build_scene

# how the last action ended: an execute() reason, "rejected" by the filter, or "none" (reset)
OUTCOMES = ("none", *REASONS, "rejected")
FIND_LENGTH_MIN_M = 0.005  # task.touch_finds_length: a touch this far past the end counts


class PrimitiveEnv(EnvBase):
    """Mid-level environment over one simulated world (batch size ``()``): a sequencer of
    primitives over the scene (``task.scene``) and the task (``task.goal_task``).

    ``goals`` fixes the episodes' (X0, Xg) pairs, taken in order (evaluation); without it each
    reset draws a fresh pair from the training distribution of the ``goals`` group, or of a
    group drawn uniformly from ``goals.train_groups`` when that lists any.
    ``states_hz`` > 0 records ``/sim/state`` snapshots at that rate of simulated time.
    ``once``: play each of ``goals`` once, then idle: a reset or a step after the last episode
    simulates nothing and returns the last observation, the step with ``done`` set (an
    evaluation whose other environments are still playing wastes no time on this one).
    """

    def __init__(self, cfg, goals: list[GoalPair] | None = None,
                 seed: int | None = None, states_hz: float = 0.0, once: bool = False):
        super().__init__(device="cpu", batch_size=torch.Size([]))
        self.scene = scene = build_scene(cfg)
        self.world, self.model, self.prim = scene.world, scene.model, scene.prim
        self.task = GoalTask.from_config(scene, cfg, goals=goals, once=once)
        self.filter = str(scene.rules.filter)
        self.noisy = bool(scene.noise.any())
        self.actions = action_table(self.prim)
        # with task.no_undo (no_undo_flip): the action that would undo the last one carried
        # out (a flip's repeat), refused
        rules = scene.rules
        self.undoes = (undo_actions(self.actions, rules.no_undo, rules.no_undo_flip)
                       if rules.no_undo or rules.no_undo_flip else None)
        self.undo: int | None = None
        # with task.no_repeat_contact: the last action, when it ended touching a link or the palm
        self.no_repeat = bool(rules.no_repeat_contact)
        self.repeat: int | None = None
        self.find_length = bool(rules.touch_finds_length)
        self.idle, self.last = False, None
        self.snapshots = None
        if states_hz > 0:
            longest = max(getattr(self.prim, k) for k in vars(self.prim)
                          if k.endswith("_duration_s"))
            self.snapshots = Snapshots(self.world, states_hz, longest)
        self.advice = None  # task.route_advice: the search graph's view, in the observation
        if scene.rules.route_advice:
            graph = cached_graph(cfg, SearchConfig(cache_dir=scene.rules.route_cache_dir))
            self.advice = RouteAdvice(graph, self.model, self.actions, scene.rules.route_cap_s)
        self.posture_advice = None  # task.posture_advice: what the posture can do for the goal
        if scene.rules.posture_advice:
            rules = scene.rules
            self.posture_advice = PostureAdvice(self.model,
                                                (rules.success_tol_m, rules.success_tol_rad))
        extra = sum(a.size for a in (self.advice, self.posture_advice) if a is not None)
        declare_mid_level_specs(self, len(self.actions), OBS_DIM + extra)
        self.observation_spec["pose"] = Unbounded(shape=(3,), dtype=torch.float32)
        self.observation_spec["valid"] = Binary(n=1, dtype=torch.bool)
        self.observation_spec["outcome"] = Categorical(len(OUTCOMES), shape=(1,))
        self.observation_spec["physics_steps"] = Unbounded(shape=(1,), dtype=torch.int64)
        self.observation_spec["wall_s"] = Unbounded(shape=(3,), dtype=torch.float64)
        self.wall = np.zeros(3)  # filter, execute, stepSimulation (s, cumulative)
        if self.snapshots is not None:
            self.observation_spec["states"] = Unbounded(
                shape=(self.snapshots.capacity, STATE_WIDTH), dtype=torch.float32)
        self.set_seed(0 if seed is None else seed)

    def _set_seed(self, seed: int | None) -> None:
        self.rng = np.random.default_rng(seed)

    def _output(self, valid: bool, outcome: str, **done) -> TensorDict:
        obs, self.offset, self.pose = self.scene.observe(self.rng)
        # contact bookkeeping from what the controllers see: the observed pose, never the true
        self.contacts = self.model.measured(self.contacts, obs.pose, obs.q)
        t = time.perf_counter()
        self.mask, self.planned = feasibility(self.actions, self.model, self.contacts,
                                              self.prim, obs)
        self.wall[0] += time.perf_counter() - t
        for a in (self.undo, self.repeat):  # task.no_undo, task.no_repeat_contact
            if a is not None and self.mask[a] and self.mask.sum() > 1:
                self.mask[a] = False
        mask = self.mask if self.filter == "mask" else np.ones_like(self.mask)
        task = self.task
        parts = [obs.q, obs.qd, obs.pose, task.goal]
        if self.advice is not None:  # read from the observed state, as the search reads it
            parts.append(self.advice(obs.q, obs.pose, task.goal))
        if self.posture_advice is not None:  # from the contacts the controllers see
            parts.append(self.posture_advice(self.contacts, task.goal))
        vec = np.concatenate(parts).astype(np.float32)
        stuck = self.filter == "mask" and not mask.any()
        flags = {k: torch.tensor([v]) for k, v in done.items()}
        if stuck:
            # No action is allowed: without noise the episode cannot go on. Under noise the
            # next observation differs (and a reset may not end an episode): any action may
            # be picked, and the one picked is refused by its primitive, as an invalid action.
            if not self.noisy and outcome != "none":
                flags["truncated"] = torch.tensor([True])
                flags["done"] = torch.tensor([True])
            mask = np.ones_like(mask)  # keep the distribution defined
        self.action_spec.update_mask(torch.from_numpy(mask))  # rand_action samples allowed ones
        td = TensorDict({
            "observation": torch.from_numpy(vec),
            "action_mask": torch.from_numpy(mask),
            "success": torch.tensor([task.success]),
            "dropped": torch.tensor([task.dropped]),
            "sim_time_s": torch.tensor([task.sim_time], dtype=torch.float32),
            "pose": torch.tensor(self.pose, dtype=torch.float32),
            "valid": torch.tensor([valid]),
            "outcome": torch.tensor([OUTCOMES.index(outcome)]),
            "physics_steps": torch.tensor([self.world.physics_steps]),
            "wall_s": torch.tensor([*self.wall[:2], self.world.step_wall_s],
                                   dtype=torch.float64),
            **flags}, batch_size=())
        if self.snapshots is not None:
            td["states"] = torch.from_numpy(self.snapshots.table())
        self.last = td
        return td

    def _lengthen_to(self, reach_m: float) -> None:
        """task.touch_finds_length: the model as long as a touch ``reach_m`` from the centre
        shows the object is, when that is past its ends by more than ``FIND_LENGTH_MIN_M``
        (observation noise moves the touch that much)."""
        extra = reach_m - self.model.shape.half_z
        if extra > FIND_LENGTH_MIN_M:
            self.model = self.model.lengthened(extra)

    # --- episodes -----------------------------------------------------------------------

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDict:
        if not self.task.reset(self.rng):
            self.idle = True
            return idle_output(self.last, done=False)
        pair = self.task.pair
        self.contacts = pair.contacts
        self.model = self.scene.model  # task.touch_finds_length: nominal again
        self.postures = {pair.contacts.posture}  # reached so far in this episode
        self.undo = self.repeat = None
        if self.snapshots is not None:
            self.snapshots.new_episode()
        false = False
        return self._output(True, "none", done=false, terminated=false, truncated=false)

    def _step(self, tensordict: TensorDictBase) -> TensorDict:
        if self.idle:
            td = idle_output(self.last, done=True)
            td["reward"] = torch.zeros(1)
            return td
        a = int(tensordict["action"])
        action, task = self.actions[a], self.task
        before = task.to_go(self.pose)  # as observed at the last output
        route_before = task.route_to_go()  # None without the route shaping
        useful, valid, outcome = False, True, "rejected"
        dropped, sim_time = False, 0.0
        if self.snapshots is not None:
            self.snapshots.new_action()
        if not self.mask[a] and self.filter != "off":
            valid = False  # rejected by the filter: no motion
        else:
            prim = self.planned[a]  # planned by the filter on this very observation
            if prim is None:
                prim = make_primitive(action, self.model, self.contacts, self.prim)
            world = self.world if self.snapshots is None else self.snapshots
            t = time.perf_counter()
            out = execute(world, prim, self.offset, started=self.planned[a] is not None,
                          settle_early=self.prim.settle_early)
            self.wall[1] += time.perf_counter() - t
            sim_time = out.sim_time_s
            valid, outcome = out.reason != "infeasible", out.reason
            if self.undoes is not None:
                self.undo = self.undoes[a] if out.ok else None
            if self.no_repeat:  # the same move would meet the same link or palm again
                self.repeat = a if out.reason == "link_contact" else None
            if self.find_length and out.reason == "link_contact":
                self._lengthen_to(out.reach_m)
            dropped = out.dropped  # from the simulated state, whatever the primitive says
            if out.reached and action.kind in ("flip", "release", "land"):
                self.contacts = prim.result
            if out.ok and action.kind == "flip":
                # paid once per posture and episode: flipping back and forth earns nothing
                fresh = self.contacts.posture not in self.postures
                self.postures.add(self.contacts.posture)
                pose, q = self.world.object_pose(), self.world.joint_q()
                useful = fresh and flip_useful(self.model, self.model.measured(
                    self.contacts, pose, q), action.finger, pose, task.goal)
        v = task.judge(dropped, sim_time, valid=valid, useful_flip=useful, before=before,
                       route_before=route_before)
        td = self._output(valid, outcome, done=v.terminated or v.truncated,
                          terminated=v.terminated, truncated=v.truncated)
        td["reward"] = torch.tensor([v.reward], dtype=torch.float32)
        return td
