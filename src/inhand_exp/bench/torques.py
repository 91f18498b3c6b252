"""What an end-to-end torque policy explores: how long random torques keep the object held, and
the torques the controllers themselves command.

The first part plays episodes of the DDPG environment (``TorqueEnv``: easy pairs, the mid
level's drop test) with torques drawn uniformly in [-s, s] for each scale ``s`` (and zero
torque), one draw per control period, and reports how long the object stays held. The second
drives the mid-level environment with a random allowed policy on medium pairs and reports the
percentiles of the joint torques the controllers send to the simulator. A policy that starts
from random torques earns the sparse +5 only where the goal is reached before the object
falls.
"""

from __future__ import annotations

import numpy as np
import torch
from omegaconf import DictConfig

from inhand_exp.control.hand import HandModel
from inhand_exp.envs.primitive_env import PrimitiveEnv
from inhand_exp.envs.torque_env import TorqueEnv
from inhand_exp.task.goals import goal_set

SCALES_NM = (0.0, 0.1, 0.3, 1.0, 10.0)
PERCENTILES = (50, 90, 99, 99.9, 100)


def held_under_random_torques(cfg: DictConfig, episodes: int, seed: int,
                              scales=SCALES_NM) -> dict[float, list[float]]:
    """Seconds each of ``episodes`` easy pairs stays held (or reaches its goal, or its time
    limit) under uniform random torques of each scale (``cfg``: with ``learner=ddpg``, whose
    ``control_period_s`` sets how long each draw is held)."""
    model = HandModel.from_config(cfg.hand, cfg.object, cfg.sim.gravity_mps2)
    pairs = goal_set(model, "easy", episodes, seed=seed)
    rng = np.random.default_rng(seed)
    env = TorqueEnv(cfg, goals=pairs, seed=seed)
    out: dict[float, list[float]] = {}
    try:
        for s in scales:
            out[s] = []
            for _ in pairs:
                td = env.reset()
                while True:
                    tau = torch.as_tensor(rng.uniform(-s, s, 6), dtype=torch.float32)
                    td = env.step(td.set("action", tau))["next"]
                    if td["done"].item():
                        break
                out[s].append(float(td["sim_time_s"]))
    finally:
        env.close()
    return out


def controller_torques(cfg: DictConfig, actions: int, seed: int) -> np.ndarray:
    """|torque| (N m) of every joint at every control step the controllers take over
    ``actions`` random allowed mid-level actions on medium pairs: (steps, 6)."""
    model = HandModel.from_config(cfg.hand, cfg.object, cfg.sim.gravity_mps2)
    pairs = goal_set(model, "medium", max(1, actions // 20), seed=seed)
    sent: list[np.ndarray] = []
    env = PrimitiveEnv(cfg, goals=pairs, seed=seed)
    step = env.scene.world.step

    def recording(tau: np.ndarray) -> None:
        sent.append(np.abs(np.asarray(tau, dtype=float)))
        step(tau)

    env.scene.world.step = recording
    rng = np.random.default_rng(seed)
    try:
        td = env.reset()
        for _ in range(actions):
            a = int(rng.choice(np.flatnonzero(td["action_mask"].numpy())))
            td = env.step(td.set("action", torch.tensor(a)))["next"]
            if td["done"].item():
                td = env.reset()
    finally:
        env.close()
    return np.clip(np.array(sent), 0.0, float(cfg.hand.max_torque_nm))


def torque_exploration(cfg: DictConfig, episodes: int, actions: int, seed: int) -> dict:
    held = held_under_random_torques(cfg, episodes, seed)
    used = controller_torques(cfg, actions, seed)
    limit = float(cfg.hand.max_torque_nm)
    print(f"time held under uniform random torques ({episodes} easy pairs, "
          f"hand.max_torque_nm={limit:g})")
    print("  scale (N m)   median (s)   max (s)")
    for s, t in held.items():
        print(f"  {s:11.2f} {np.median(t):12.3f} {max(t):9.3f}")
    pct = np.percentile(used, PERCENTILES).tolist()
    print(f"controllers' |torque| over {len(used)} control steps x 6 joints "
          f"({actions} random allowed actions, medium pairs):")
    print("  " + "  ".join(f"p{p:g}={v:.3f}" for p, v in zip(PERCENTILES, pct, strict=True))
          + f" N m; at the limit: {np.mean(used >= limit - 1e-9):.3%} of joint steps")
    return {"episodes": episodes, "max_torque_nm": limit,
            "held_median_s": {str(s): round(float(np.median(t)), 4) for s, t in held.items()},
            "held_max_s": {str(s): round(float(max(t)), 4) for s, t in held.items()},
            "controller_steps": len(used),
            "controller_abs_torque_pct": {f"{p:g}": v for p, v in zip(PERCENTILES, pct,
                                                                     strict=True)},
            "controller_at_limit": float(np.mean(used >= limit - 1e-9))}
