"""Toy stand-ins for the environments, with known best policies, to test learners fast.

``ToyLineEnv`` stands in for the primitive environment, ``ToyReachEnv`` for the torque one.


The state is a position on a line of ``size`` cells and a goal cell; action 0 steps right,
action 1 steps left, every other action is masked out (as infeasible primitives are). Reaching the
goal pays +5 and ends the episode; ``max_steps`` actions truncate it. Same keys and specs as
``PrimitiveEnv``: ``observation`` (18 floats), ``action_mask``, ``success``, ``dropped``,
``sim_time_s``; the position and the goal are the x of ``X_t`` and ``X_g``.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Binary, Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from inhand_exp.envs.specs import OBS_DIM, declare_mid_level_specs

CELL_M = 0.01  # a cell is one repose step along x


class ToyLineEnv(EnvBase):
    def __init__(self, n_actions: int = 14, size: int = 8, max_steps: int = 12,
                 seed: int = 0):
        super().__init__(device="cpu", batch_size=torch.Size([]))
        self.n, self.size, self.max_steps = n_actions, size, max_steps
        declare_mid_level_specs(self, n_actions)
        self.set_seed(seed)

    def _set_seed(self, seed: int | None) -> None:
        self.gen = torch.Generator().manual_seed(0 if seed is None else seed)

    def _out(self, success: bool, done: bool, truncated: bool) -> TensorDict:
        obs = torch.zeros(OBS_DIM)
        obs[12:15] = torch.tensor([CELL_M * self.pos, 0.2, 0.0])  # X_t
        obs[15:18] = torch.tensor([CELL_M * self.goal, 0.2, 0.0])  # X_g
        mask = torch.zeros(self.n, dtype=torch.bool)
        mask[:2] = True
        self.action_spec.update_mask(mask)
        return TensorDict({
            "observation": obs, "action_mask": mask,
            "success": torch.tensor([success]), "dropped": torch.tensor([False]),
            "sim_time_s": torch.tensor([float(self.steps)]),
            "done": torch.tensor([done]), "terminated": torch.tensor([done and not truncated]),
            "truncated": torch.tensor([truncated])}, batch_size=())

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDict:
        self.pos, self.goal = (int(v) for v in torch.randint(0, self.size, (2,),
                                                                 generator=self.gen))
        while self.goal == self.pos:
            self.goal = int(torch.randint(0, self.size, (1,), generator=self.gen))
        self.steps = 0
        return self._out(False, False, False)

    def _step(self, tensordict: TensorDictBase) -> TensorDict:
        a = int(tensordict["action"])
        if a in (0, 1):
            self.pos = min(self.size - 1, max(0, self.pos + (1 if a == 0 else -1)))
        self.steps += 1
        success = self.pos == self.goal
        truncated = not success and self.steps >= self.max_steps
        td = self._out(success, success or truncated, truncated)
        td["reward"] = torch.tensor([5.0 if success else (0.0 if a in (0, 1) else -0.01)])
        return td


class ToyReachEnv(EnvBase):
    """A continuous toy for the torque learners: move a point on [-1, 1] to a goal.

    The action has six entries in [-``max_torque``, ``max_torque``], like the hand's torques;
    only the first moves the point, by ``speed`` x action per step. The point is ``X_t``'s x
    and the goal ``X_g``'s x in the 18-float ``observation``. Each step pays minus the
    distance, reaching within ``tol`` pays +5 and ends the episode; ``max_steps`` truncate it.
    """

    def __init__(self, max_torque: float = 1.0, speed: float = 0.2, tol: float = 0.1,
                 max_steps: int = 20, seed: int = 0):
        super().__init__(device="cpu", batch_size=torch.Size([]))
        self.max_torque, self.speed, self.tol, self.max_steps = max_torque, speed, tol, max_steps
        self.observation_spec = Composite(
            observation=Unbounded(shape=(OBS_DIM,), dtype=torch.float32),
            success=Binary(n=1, dtype=torch.bool), dropped=Binary(n=1, dtype=torch.bool))
        self.action_spec = Bounded(-max_torque, max_torque, shape=(6,), dtype=torch.float32)
        self.reward_spec = Unbounded(shape=(1,), dtype=torch.float32)
        self.full_done_spec = Composite(
            done=Categorical(2, shape=(1,), dtype=torch.bool),
            terminated=Categorical(2, shape=(1,), dtype=torch.bool),
            truncated=Categorical(2, shape=(1,), dtype=torch.bool))
        self.set_seed(seed)

    def _set_seed(self, seed: int | None) -> None:
        self.gen = torch.Generator().manual_seed(0 if seed is None else seed)

    def _out(self, success: bool, truncated: bool) -> TensorDict:
        obs = torch.zeros(OBS_DIM)
        obs[12], obs[15] = self.pos, self.goal
        return TensorDict({
            "observation": obs, "success": torch.tensor([success]),
            "dropped": torch.tensor([False]), "done": torch.tensor([success or truncated]),
            "terminated": torch.tensor([success]), "truncated": torch.tensor([truncated])},
            batch_size=())

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDict:
        self.pos, self.goal = (float(v) for v in torch.rand(2, generator=self.gen) * 2 - 1)
        self.steps = 0
        return self._out(False, False)

    def _step(self, tensordict: TensorDictBase) -> TensorDict:
        a = float(tensordict["action"][0]) / self.max_torque
        self.pos = min(1.0, max(-1.0, self.pos + self.speed * max(-1.0, min(1.0, a))))
        self.steps += 1
        gap = abs(self.pos - self.goal)
        success = gap < self.tol
        td = self._out(success, not success and self.steps >= self.max_steps)
        td["reward"] = torch.tensor([5.0 if success else -gap])
        return td
