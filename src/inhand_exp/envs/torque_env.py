"""The end-to-end TorchRL environment of the DDPG baseline (paper section IV-A): six torques.

One step applies the action, the six joint torques (N m, bounded by ``hand.max_torque_nm``), for
``control_period_s`` of simulated time (``learner.control_period_s``, a whole number of control
periods). Everything else is the mid level's, through the same scene and task object:

- observation: q, qd (12), the observed object pose ``X_t`` (3, noisy under ``noise=paper``)
  and the goal ``X_g`` (3), as ``observation``; ``success``, ``dropped``, ``sim_time_s`` and the
  true ``pose`` beside it for evaluation;
- success from the simulated pose within the task's tolerances;
- the drop test of ``control.execute``: the object not held (PyBullet's contacts) for
  ``DROP_GRACE_S``, or the simulation blowing up;
- reward: the paper's sparse +5 at the goal (``task.reward_progress`` is the mid level's and is
  not paid here);
- time limit: ``task.time_limit_s`` simulated seconds.

``valid`` is always true (every torque is a legal action) and ``outcome`` says how the step ended
(``none``, ``running``, ``dropped``, ``unstable``), so that ``learn.evaluate`` reads this
environment as it reads the mid level.
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Binary, Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from inhand_exp.control.execute import DROP_GRACE_S
from inhand_exp.envs.snapshots import STATE_WIDTH, Snapshots
from inhand_exp.envs.specs import OBS_DIM, idle_output
from inhand_exp.sim.world import NonFiniteTorque, state_problem
from inhand_exp.task.goal_task import GoalTask
from inhand_exp.task.goals import GoalPair
from inhand_exp.task.scene import build_scene

OUTCOMES = ("none", "running", "dropped", "unstable")
DEFAULT_PERIOD_S = 1 / 60


def control_period(cfg) -> float:
    """``learner.control_period_s`` when the learner has one (DDPG), else 1/60 s."""
    return float(cfg["learner"].get("control_period_s", DEFAULT_PERIOD_S))


class TorqueEnv(EnvBase):
    """End-to-end environment over one simulated world (batch size ``()``).

    ``goals``, ``once`` and ``states_hz`` as for ``PrimitiveEnv``.
    """

    def __init__(self, cfg, goals: list[GoalPair] | None = None, seed: int | None = None,
                 states_hz: float = 0.0, once: bool = False):
        super().__init__(device="cpu", batch_size=torch.Size([]))
        self.scene = scene = build_scene(cfg)
        self.world = scene.world
        pool = int(cfg["learner"].get("train_pool", 0))
        self.task = GoalTask.from_config(scene, cfg, end_to_end=True, goals=goals, once=once,
                                         pool=pool)
        period = control_period(cfg)
        self.steps = round(period / self.world.dt)
        if self.steps < 1 or abs(self.steps * self.world.dt - period) > 1e-9:
            raise ValueError(f"control period {period} s is not a whole number of control "
                             f"periods of {self.world.dt} s")
        self.period_s = self.steps * self.world.dt
        self.idle, self.last, self.lost_for = False, None, 0.0
        self.snapshots = Snapshots(self.world, states_hz, self.period_s) if states_hz > 0 \
            else None
        limit = float(self.world.max_torque)
        self.observation_spec = Composite(
            observation=Unbounded(shape=(OBS_DIM,), dtype=torch.float32),
            success=Binary(n=1, dtype=torch.bool),
            dropped=Binary(n=1, dtype=torch.bool),
            sim_time_s=Unbounded(shape=(1,), dtype=torch.float32),
            pose=Unbounded(shape=(3,), dtype=torch.float32),
            valid=Binary(n=1, dtype=torch.bool),
            outcome=Categorical(len(OUTCOMES), shape=(1,)),
            physics_steps=Unbounded(shape=(1,), dtype=torch.int64))
        if self.snapshots is not None:
            self.observation_spec["states"] = Unbounded(
                shape=(self.snapshots.capacity, STATE_WIDTH), dtype=torch.float32)
        self.action_spec = Bounded(-limit, limit, shape=(6,), dtype=torch.float32)
        self.reward_spec = Unbounded(shape=(1,), dtype=torch.float32)
        self.full_done_spec = Composite(
            done=Categorical(2, shape=(1,), dtype=torch.bool),
            terminated=Categorical(2, shape=(1,), dtype=torch.bool),
            truncated=Categorical(2, shape=(1,), dtype=torch.bool))
        self.set_seed(0 if seed is None else seed)

    def _set_seed(self, seed: int | None) -> None:
        self.rng = np.random.default_rng(seed)

    def _output(self, outcome: str, **done) -> TensorDict:
        obs, _, pose = self.scene.observe(self.rng)
        task = self.task
        vec = np.concatenate([obs.q, obs.qd, obs.pose, task.goal]).astype(np.float32)
        td = TensorDict({
            "observation": torch.from_numpy(vec),
            "success": torch.tensor([task.success]),
            "dropped": torch.tensor([task.dropped]),
            "sim_time_s": torch.tensor([task.sim_time], dtype=torch.float32),
            "pose": torch.tensor(pose, dtype=torch.float32),
            "valid": torch.tensor([True]),
            "outcome": torch.tensor([OUTCOMES.index(outcome)]),
            "physics_steps": torch.tensor([self.world.physics_steps]),
            **{k: torch.tensor([v]) for k, v in done.items()}}, batch_size=())
        if self.snapshots is not None:
            td["states"] = torch.from_numpy(self.snapshots.table())
        self.last = td
        return td

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDict:
        if not self.task.reset(self.rng):
            self.idle = True
            return idle_output(self.last, done=False)
        self.lost_for = 0.0
        if self.snapshots is not None:
            self.snapshots.new_episode()
        return self._output("none", done=False, terminated=False, truncated=False)

    def _step(self, tensordict: TensorDictBase) -> TensorDict:
        if self.idle:
            td = idle_output(self.last, done=True)
            td["reward"] = torch.zeros(1)
            return td
        tau = tensordict["action"].detach().double().numpy()
        world = self.world if self.snapshots is None else self.snapshots
        if self.snapshots is not None:
            self.snapshots.new_action()
        outcome = "running"
        try:
            for _ in range(self.steps):
                world.step(tau)
        except NonFiniteTorque:
            outcome = "unstable"  # a NaN torque ends the episode as a failure
        else:
            pose, twist = self.world.object_state()
            q, qd = self.world.joint_state()
            if state_problem(pose, twist, q, qd) is not None:
                outcome = "unstable"
            elif self.world.grasp_lost() is not None:
                self.lost_for += self.period_s
                if self.lost_for >= DROP_GRACE_S - 1e-9:
                    outcome = "dropped"
            else:
                self.lost_for = 0.0
        v = self.task.judge(outcome in ("dropped", "unstable"), self.period_s)
        td = self._output(outcome, done=v.terminated or v.truncated, terminated=v.terminated,
                          truncated=v.truncated)
        td["reward"] = torch.tensor([v.reward], dtype=torch.float32)
        return td
