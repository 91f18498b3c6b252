"""The mid-level TorchRL environment (paper section III-B): one step is one primitive.

Clocks: the policy acts once per primitive; the primitive's torque law runs every control period
(``sim.timestep_s`` x ``sim.control_substeps``) for the primitive's duration, or until it has
settled (``primitives.settle_early``). Observation (paper IV-A): joint angles and
velocities (12), the observed object pose ``X_t`` (3, with uniform noise under ``noise=paper``)
and the goal ``X_g`` (3); ``action_mask`` says which actions the feasibility filter allows.
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
from omegaconf import DictConfig
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Binary, Categorical, Unbounded
from torchrl.envs import EnvBase

from inhand_exp.config import ObjectConfig, PerturbConfig
from inhand_exp.control.execute import REASONS, Observation, execute
from inhand_exp.control.hand import HandModel
from inhand_exp.control.repose import Gains
from inhand_exp.control.sample import Workspace
from inhand_exp.envs.snapshots import STATE_WIDTH, Snapshots
from inhand_exp.envs.specs import declare_mid_level_specs
from inhand_exp.sim.world import ObjectSpec, World
from inhand_exp.task.actions import action_table, feasibility, make_primitive
from inhand_exp.task.goals import GoalPair, sample_pair
from inhand_exp.task.rules import Rules, flip_useful, reached, reward, to_go

PRESS_M = 0.0005  # initial fingertip press into the surface (m)
# how the last action ended: an execute() reason, "rejected" by the filter, or "none" (reset)
OUTCOMES = ("none", *REASONS, "rejected")


def _object_config(node) -> ObjectConfig:
    return ObjectConfig(**{k: node[k] for k in node})


class PrimitiveEnv(EnvBase):
    """Mid-level environment over one simulated world (batch size ``()``).

    ``goals`` fixes the episodes' (X0, Xg) pairs, taken in order (evaluation); without it each
    reset draws a fresh pair from the training distribution of the ``goals`` group, or of a
    group drawn uniformly from ``goals.train_groups`` when that lists any.
    ``states_hz`` > 0 records ``/sim/state`` snapshots at that rate of simulated time.
    ``once``: play each of ``goals`` once, then idle: a reset or a step after the last episode
    simulates nothing and returns the last observation, the step with ``done`` set (an
    evaluation whose other environments are still playing wastes no time on this one).
    """

    def __init__(self, cfg: DictConfig, goals: list[GoalPair] | None = None,
                 seed: int | None = None, states_hz: float = 0.0, once: bool = False):
        super().__init__(device="cpu", batch_size=torch.Size([]))
        obj = _object_config(cfg.object)
        p = cfg.perturb
        perturb = PerturbConfig(p.name, p.mass_scale, p.width_scale, p.length_scale)
        g = cfg.sim.gravity_mps2
        self.world = World(cfg.sim, cfg.hand, ObjectSpec.from_config(obj, perturb))
        self.model = HandModel.from_config(cfg.hand, obj, g)  # what the controllers know
        true_obj = ObjectConfig(obj.name, obj.length_m * p.length_scale,
                                obj.width_m * p.width_scale, obj.depth_m,
                                obj.mass_kg * p.mass_scale, obj.friction)
        self.true_model = HandModel.from_config(cfg.hand, true_obj, g)  # to touch the surface
        self.prim = cfg.primitives
        self.groups = tuple(cfg.goals.train_groups) or (cfg.goals.name,)
        self.workspace = Workspace.from_config(cfg.task)
        self.hard_posture = cfg.goals.hard_goal_posture
        self.gains, self.rules = Gains.from_config(cfg.primitives), Rules.from_config(cfg.task)
        self.filter = str(cfg.task.filter.value if hasattr(cfg.task.filter, "value")
                          else cfg.task.filter)
        self.noise = np.array([cfg.noise.xz_m, cfg.noise.xz_m, cfg.noise.theta_rad])
        self.actions = action_table(cfg.primitives)
        self.goals, self.episode = goals, 0
        self.once, self.idle, self.last = once and goals is not None, False, None
        self.snapshots = None
        if states_hz > 0:
            longest = max(v for k, v in cfg.primitives.items() if k.endswith("_duration_s"))
            self.snapshots = Snapshots(self.world, states_hz, longest)
        declare_mid_level_specs(self, len(self.actions))
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

    # --- seeding and observing ----------------------------------------------------------

    def _set_seed(self, seed: int | None) -> None:
        self.rng = np.random.default_rng(seed)

    def _observe(self) -> tuple[Observation, np.ndarray, np.ndarray]:
        """The controllers' and the policy's view (true joints, object pose with noise), the
        noise drawn, and the true pose."""
        pose, twist = self.world.object_state()
        q, qd = self.world.joint_state()
        offset = self.rng.uniform(-self.noise, self.noise) if self.noise.any() else np.zeros(3)
        return Observation(q, qd, pose + offset, twist, 0.0), offset, pose

    def _output(self, valid: bool, outcome: str, **done) -> TensorDict:
        obs, self.offset, self.pose = self._observe()
        # contact bookkeeping from what the controllers see: the observed pose, never the true
        self.contacts = self.model.measured(self.contacts, obs.pose, obs.q)
        t = time.perf_counter()
        self.mask, self.planned = feasibility(self.actions, self.model, self.contacts,
                                              self.gains, self.prim, obs)
        self.wall[0] += time.perf_counter() - t
        mask = self.mask if self.filter == "mask" else np.ones_like(self.mask)
        vec = np.concatenate([obs.q, obs.qd, obs.pose, self.goal]).astype(np.float32)
        stuck = self.filter == "mask" and not mask.any()
        flags = {k: torch.tensor([v]) for k, v in done.items()}
        if stuck:
            # No action is allowed: without noise the episode cannot go on. Under noise the
            # next observation differs (and a reset may not end an episode): any action may
            # be picked, and the one picked is refused by its primitive, as an invalid action.
            if not self.noise.any() and outcome != "none":
                flags["truncated"] = torch.tensor([True])
                flags["done"] = torch.tensor([True])
            mask = np.ones_like(mask)  # keep the distribution defined
        self.action_spec.update_mask(torch.from_numpy(mask))  # rand_action samples allowed ones
        td = TensorDict({
            "observation": torch.from_numpy(vec),
            "action_mask": torch.from_numpy(mask),
            "success": torch.tensor([self.success]),
            "dropped": torch.tensor([self.dropped]),
            "sim_time_s": torch.tensor([self.sim_time], dtype=torch.float32),
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

    def _idle_output(self, done: bool) -> TensorDict:
        td = self.last.clone()
        for key in ("done", "truncated"):
            td[key] = torch.tensor([done])
        td["terminated"] = torch.tensor([False])
        return td

    # --- episodes -----------------------------------------------------------------------

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDict:
        if self.once and self.episode >= len(self.goals):
            self.idle = True
            return self._idle_output(done=False)
        if self.goals is not None:
            pair = self.goals[self.episode % len(self.goals)]
        else:
            group = self.groups[int(self.rng.integers(len(self.groups)))] \
                if len(self.groups) > 1 else self.groups[0]
            pair = sample_pair(self.model, group, self.rng, self.workspace, self.hard_posture)
        self.episode += 1
        self.pair, self.goal, self.contacts = pair, pair.xg.copy(), pair.contacts
        self.postures = {pair.contacts.posture}  # reached so far in this episode
        self.world.reset(pair.x0, self.true_model.grasp_q(pair.contacts, pair.x0, PRESS_M))
        if self.snapshots is not None:
            self.snapshots.new_episode()
        self.n_actions, self.n_invalid, self.sim_time = 0, 0, 0.0
        self.success, self.dropped = False, False
        false = False
        return self._output(True, "none", done=false, terminated=false, truncated=false)

    def _step(self, tensordict: TensorDictBase) -> TensorDict:
        if self.idle:
            td = self._idle_output(done=True)
            td["reward"] = torch.zeros(1)
            return td
        a = int(tensordict["action"])
        action = self.actions[a]
        before = to_go(self.pose, self.goal, self.rules)  # as observed at the last output
        allowed = bool(self.mask[a])
        useful, valid, outcome = False, True, "rejected"
        if self.snapshots is not None:
            self.snapshots.new_action()
        if not allowed and self.filter != "off":
            valid = False  # rejected by the filter: no motion
        else:
            prim = self.planned[a]  # planned by the filter on this very observation
            if prim is None:
                prim = make_primitive(action, self.model, self.contacts, self.gains, self.prim)
            world = self.world if self.snapshots is None else self.snapshots
            t = time.perf_counter()
            out = execute(world, prim, self.offset, started=self.planned[a] is not None,
                          settle_early=self.prim.settle_early)
            self.wall[1] += time.perf_counter() - t
            self.sim_time += out.sim_time_s
            valid, outcome = out.reason != "infeasible", out.reason
            self.dropped = out.dropped  # from the simulated state, whatever the primitive says
            if out.reached and action.kind in ("flip", "release", "land"):
                self.contacts = prim.result
            if out.ok and action.kind == "flip":
                # paid once per posture and episode: flipping back and forth earns nothing
                fresh = self.contacts.posture not in self.postures
                self.postures.add(self.contacts.posture)
                pose, q = self.world.object_pose(), self.world.joint_q()
                useful = fresh and flip_useful(self.model, self.model.measured(
                    self.contacts, pose, q), action.finger, pose, self.goal)
        self.n_invalid += not valid
        self.n_actions += 1
        after = self.world.object_pose()
        self.success = not self.dropped and reached(after, self.goal, self.rules)
        terminated = self.success or self.dropped
        truncated = not terminated and self.n_actions >= self.rules.max_actions
        r = reward(self.rules, valid=valid, success=self.success, useful_flip=useful,
                   progress=before - to_go(after, self.goal, self.rules))
        td = self._output(valid, outcome, done=terminated or truncated, terminated=terminated,
                          truncated=truncated)
        td["reward"] = torch.tensor([r], dtype=torch.float32)
        return td
