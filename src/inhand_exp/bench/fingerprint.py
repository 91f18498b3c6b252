"""A fingerprint of the mid level's behaviour: does a change keep every decision, bit for bit?

One environment plays ``actions`` random allowed actions (seeded) on the configured goal group.
After each, the feasibility mask, how the action ended and the simulated state (the object's and
the joints' positions and velocities, float64) go into one SHA-256: two codes with the same
fingerprint made the same decisions from the same states. ``out`` keeps the masks, outcomes
and object poses of the run (``.npz``); ``against`` compares this run with one kept earlier, for
a change that rounds differently and so cannot keep the fingerprint: how many masks and
outcomes differ, and the largest difference of the object's pose.
"""

from __future__ import annotations

import hashlib
from collections import Counter
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig

from inhand_exp.config import ConfigError
from inhand_exp.envs.primitive_env import OUTCOMES, PrimitiveEnv


def fingerprint(cfg: DictConfig, actions: int, seed: int, out: Path | None = None,
                against: Path | None = None) -> dict:
    """Play ``actions`` random allowed actions; the fingerprint and what went into it."""
    earlier = _kept(against, actions) if against is not None else None
    env = PrimitiveEnv(cfg, seed=seed)
    gen = torch.Generator().manual_seed(seed)
    digest, masks, outcomes, poses = hashlib.sha256(), [], [], []
    try:
        td = env.reset()
        for _ in range(actions):
            allowed = td["action_mask"].float()
            td["action"] = torch.multinomial(allowed, 1, generator=gen).squeeze()
            td = env.step(td)["next"]
            pose, twist = env.world.object_state()
            q, qd = env.world.joint_state()
            mask, outcome = td["action_mask"].numpy().copy(), int(td["outcome"])
            for part in (mask, np.array([outcome]), pose, twist, q, qd):
                digest.update(np.ascontiguousarray(part).tobytes())
            masks.append(mask)
            outcomes.append(outcome)
            poses.append(pose)
            if td["done"].item():
                td = env.reset()
    finally:
        env.close()
    run = {"masks": np.array(masks), "outcomes": np.array(outcomes), "poses": np.array(poses)}
    if out is not None:
        np.savez(out, **run)
    counts = Counter(OUTCOMES[k] for k in outcomes)
    result = {"actions": actions, "seed": seed, "goals": str(cfg.goals.name),
              "fingerprint": digest.hexdigest()[:16], "outcomes": dict(sorted(counts.items()))}
    print(f"{actions} random allowed actions on {result['goals']} goals (seed {seed}): "
          f"fingerprint {result['fingerprint']}; outcomes {result['outcomes']}")
    if earlier is not None:
        result["against"] = {
            "masks_differing": int((run["masks"] != earlier["masks"]).any(axis=1).sum()),
            "outcomes_differing": int((run["outcomes"] != earlier["outcomes"]).sum()),
            "max_pose_diff": float(np.abs(run["poses"] - earlier["poses"]).max())}
        a = result["against"]
        print(f"against {against}: {a['masks_differing']} masks and {a['outcomes_differing']} "
              f"outcomes differ; object poses at most {a['max_pose_diff']:.3g} apart")
    return result


def _kept(path: Path, actions: int) -> dict[str, np.ndarray]:
    """The run kept in ``path`` by ``out``, checked to be one of ``actions`` actions."""
    try:
        with np.load(path) as data:
            kept = {k: data[k] for k in ("masks", "outcomes", "poses")}
    except (OSError, ValueError, KeyError) as err:
        raise ConfigError(f"{path}: not a fingerprint run kept with --out ({err})") from None
    if len(kept["poses"]) != actions:
        raise ConfigError(f"{path} holds {len(kept['poses'])} actions, this run plays {actions}:"
                          f" give the same --actions")
    return kept
