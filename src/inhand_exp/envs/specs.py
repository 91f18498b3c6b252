"""The specs every mid-level environment declares (the primitive env and the toy alike)."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.data import Binary, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from inhand_exp.task.actions import action_table
from inhand_exp.task.posture_advice import PostureAdvice

OBS_DIM = 18  # q (6), qd (6), X_t (3), X_g (3)


def advice_size(cfg) -> int:
    """Floats appended to the observation: ``task.route_advice``'s (``task.route.RouteAdvice``:
    the route time, and one per mid-level action), then ``task.posture_advice``'s two flags
    (``task.posture_advice.PostureAdvice``); 0 without either."""
    task = cfg["task"]
    n = 1 + len(action_table(cfg["primitives"])) if bool(task.get("route_advice", False)) else 0
    return n + (PostureAdvice.size if bool(task.get("posture_advice", False)) else 0)


def declare_mid_level_specs(env: EnvBase, n_actions: int, obs_dim: int = OBS_DIM) -> None:
    """Observation (``observation`` of ``obs_dim`` floats, ``action_mask``, ``success``,
    ``dropped``, ``sim_time_s``), a categorical action over ``n_actions``, a scalar reward and
    done/terminated/truncated."""
    env.observation_spec = Composite(
        observation=Unbounded(shape=(obs_dim,), dtype=torch.float32),
        action_mask=Binary(n=n_actions, dtype=torch.bool),
        success=Binary(n=1, dtype=torch.bool),
        dropped=Binary(n=1, dtype=torch.bool),
        sim_time_s=Unbounded(shape=(1,), dtype=torch.float32))
    env.action_spec = Categorical(n_actions)
    env.reward_spec = Unbounded(shape=(1,), dtype=torch.float32)
    env.full_done_spec = Composite(
        done=Categorical(2, shape=(1,), dtype=torch.bool),
        terminated=Categorical(2, shape=(1,), dtype=torch.bool),
        truncated=Categorical(2, shape=(1,), dtype=torch.bool))


def idle_output(last: TensorDictBase, done: bool) -> TensorDictBase:
    """What an environment that has played its goals (``once``) returns: its last observation,
    truncated (``done``) on a step, never terminated."""
    td = last.clone()
    for key in ("done", "truncated"):
        td[key] = torch.tensor([done])
    td["terminated"] = torch.tensor([False])
    return td
