"""A toy stand-in for the primitive environment with a known best policy, to test learners fast.

The state is a position on a line of ``size`` cells and a goal cell; action 0 steps right,
action 1 steps left, every other action is masked out (as infeasible primitives are). Reaching the
goal pays +5 and ends the episode; ``max_steps`` actions truncate it. Same keys and specs as
``PrimitiveEnv``: ``observation`` (18 floats), ``action_mask``, ``success``, ``dropped``,
``sim_time_s``; the position and the goal are the x of ``X_t`` and ``X_g``.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
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
