"""Evaluation (paper section IV): episodes on a fixed goal set, judged from the simulated state.

Each episode yields one record (the ``/eval/episode`` fields); the summary has the success, drop
and timeout rates and the mean simulated time of the successful episodes.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from inhand_exp.envs.primitive_env import PrimitiveEnv
from inhand_exp.task.rules import pose_error

Record = dict[str, Any]


def run_episode(env: PrimitiveEnv, policy, episode: int) -> Record:
    """One episode from the env's next goal pair; the policy acts on its most likely action."""
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        td = env.rollout(env.rules.max_actions + 1, policy=policy, break_when_any_done=True)
    last = td[-1]["next"]
    success, dropped = bool(last["success"]), bool(last["dropped"])
    final = env.world.object_pose()
    ex, ez, eth = pose_error(final, env.goal)
    return {"episode": episode, "group": env.pair.group, "success": success,
            "dropped": dropped, "timeout": not (success or dropped),
            "sim_time_s": float(env.sim_time), "n_actions": int(env.n_actions),
            "n_invalid": int(env.n_invalid), "x0": env.pair.x0.tolist(),
            "xg": env.goal.tolist(), "final_pose": final.tolist(),
            "final_err_m": float(np.hypot(ex, ez)), "final_err_rad": float(eth)}


def evaluate(env: PrimitiveEnv, policy, episodes: int,
             on_episode: Callable[[Record], None] | None = None) -> dict[str, float]:
    """Run ``episodes`` episodes and summarise them."""
    records = []
    for k in range(episodes):
        rec = run_episode(env, policy, k)
        records.append(rec)
        if on_episode is not None:
            on_episode(rec)
    return summarise(records)


def summarise(records: list[Record]) -> dict[str, float]:
    n = len(records)
    wins = [r for r in records if r["success"]]
    return {"episodes": n,
            "success_rate": len(wins) / n,
            "drop_rate": sum(r["dropped"] for r in records) / n,
            "timeout_rate": sum(r["timeout"] for r in records) / n,
            "avg_time_s": float(np.mean([r["sim_time_s"] for r in wins])) if wins else float("nan")}
