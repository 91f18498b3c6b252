"""Mid-level throughput: actions per second of the batched primitive environment.

A uniformly random policy over the allowed actions drives ``train.num_envs`` environments in
``workers`` processes (the training layout); the simulated time of the actions, over the wall
time and the raw ``stepSimulation`` rate, tells how much of the machine the physics gets.
"""

from __future__ import annotations

import time

import torch
from omegaconf import DictConfig

from inhand_exp.envs.batched import batched_env, layout


def env_throughput(cfg: DictConfig, workers: int, steps: int, seed: int,
                   raw_steps_per_s: float) -> dict:
    cfg.train.workers = workers
    used, per = layout(cfg)
    env = batched_env(cfg, seed)
    gen = torch.Generator().manual_seed(seed)

    def random_allowed(td):
        mask = td["action_mask"].reshape(-1, td["action_mask"].shape[-1]).float()
        pick = torch.multinomial(mask, 1, generator=gen).reshape(td.shape)
        return td.set("action", pick)

    try:
        td = env.reset()
        actions, sim_s = 0, 0.0
        start = time.perf_counter()
        for _ in range(steps):
            before = td["sim_time_s"].clone()
            td, root = env.step_and_maybe_reset(random_allowed(td))
            sim_s += float((td["next", "sim_time_s"] - before).sum())
            actions += td.numel()
            td = root
        wall = time.perf_counter() - start
    finally:
        env.close()
    physics = sim_s / cfg.sim.timestep_s / wall
    out = {"workers": used, "envs_per_worker": per, "actions": actions, "wall_s": wall,
           "actions_per_s": actions / wall, "sim_s_per_action": sim_s / actions,
           "physics_steps_per_s": physics, "raw_steps_per_s": raw_steps_per_s,
           "ratio_per_worker": physics / used / raw_steps_per_s}
    print(f"stepSimulation alone: {raw_steps_per_s:10.0f} steps/s (one process, same run)")
    print(f"{used} worker(s) x {per} envs: {out['actions_per_s']:.1f} actions/s "
          f"({actions} actions in {wall:.1f} s, {sim_s / actions:.2f} s simulated each); "
          f"physics {physics:.0f} steps/s = {out['ratio_per_worker']:.1%} of raw per worker")
    return out
