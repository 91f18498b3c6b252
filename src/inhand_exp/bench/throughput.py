"""Mid-level throughput: actions per second of the batched primitive environment.

A uniformly random policy over the allowed actions drives ``train.num_envs`` environments in
``workers`` processes (the training layout). The efficiency figure is the physics steps the
environments took per second (``sim_steps_per_s``, counted by the worlds themselves) over what
the same number of processes would take calling bare ``stepSimulation`` (``raw_steps_per_s``,
measured in this run, times the workers): the share of the machine the physics gets. The rest
goes to the feasibility filter, the controllers' Python, TorchRL and the policy.

``physics_share`` is the same share taken within the run: the wall time the workers spent
inside ``stepSimulation`` over all the worker time (the run's wall time times the workers).
Both of its terms are measured over the same seconds, so a machine whose speed drifts between
the raw measurement and the run moves it much less than ``efficiency``.
"""

from __future__ import annotations

import time

import torch
from omegaconf import DictConfig

from inhand_exp.envs.batched import batched_env, layout


def env_throughput(cfg: DictConfig, workers: int, steps: int, seed: int,
                   raw_steps_per_core: float) -> dict:
    """Drive the batch for ``steps`` batch steps; the figures as a dict (see the module)."""
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
        actions, sim_s, sim_steps = 0, 0.0, 0
        spent = torch.zeros(3, dtype=torch.float64)  # filter, execute, stepSimulation
        start = time.perf_counter()
        for _ in range(steps):
            before, counted = td["sim_time_s"].clone(), td["physics_steps"].clone()
            used_before = td["wall_s"].clone()
            td, root = env.step_and_maybe_reset(random_allowed(td))
            sim_s += float((td["next", "sim_time_s"] - before).double().sum())
            sim_steps += int((td["next", "physics_steps"] - counted).sum())
            spent += (td["next", "wall_s"] - used_before).reshape(-1, 3).sum(0)
            actions += td.numel()
            td = root
        wall = time.perf_counter() - start
    finally:
        env.close()
    raw = raw_steps_per_core * used
    out = {"workers": used, "envs_per_worker": per, "actions": actions, "wall_s": wall,
           "actions_per_s": actions / wall, "sim_s_per_action": sim_s / actions,
           "sim_steps": sim_steps, "sim_steps_per_action": sim_steps / actions,
           "sim_steps_per_s": sim_steps / wall, "raw_steps_per_core": raw_steps_per_core,
           "raw_steps_per_s": raw, "efficiency": sim_steps / wall / raw,
           "physics_share": float(spent[2]) / (wall * used),
           "physics_dt_s": cfg.sim.timestep_s,
           # per action, in the environments' own processes (ms): the feasibility filter,
           # executing the primitive, and stepSimulation inside that
           "ms_per_action": dict(zip(("filter", "execute", "step_simulation"),
                                     (1e3 * spent / actions).tolist(), strict=True))}
    print(f"stepSimulation alone: {raw_steps_per_core:10.0f} steps/s per core (same run)")
    print(f"{used} worker(s) x {per} envs: {out['actions_per_s']:.1f} actions/s "
          f"({actions} actions in {wall:.1f} s, {sim_s / actions:.2f} s simulated each); "
          f"physics {out['sim_steps_per_s']:.0f} steps/s of {raw:.0f} raw: "
          f"efficiency {out['efficiency']:.1%} (inside stepSimulation: "
          f"{out['physics_share']:.1%} of the workers' time)")
    ms = out["ms_per_action"]
    print(f"per action, in each worker: filter {ms['filter']:.1f} ms, execute "
          f"{ms['execute']:.1f} ms (stepSimulation {ms['step_simulation']:.1f} ms); "
          f"{1e3 * wall * used / actions:.1f} ms of worker time in all")
    return out
