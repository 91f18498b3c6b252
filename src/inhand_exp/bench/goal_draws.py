"""What a reset costs: wall time to draw one training pair of each goal group.

Every training episode starts from a fresh (X0, Xg) pair drawn by rejection sampling
(``goals.sample_pair``: grasps that reach, keep the links clear and squeeze, and for hard pairs
the postures flips lead to), so the draw is paid once per episode, in the environment's own
process, between two mid-level actions. The figures are per pair, one process, with the
``goals`` config of the run (workspace, hard-goal posture, reachable-only, tolerances).
"""

from __future__ import annotations

import time

import numpy as np
from omegaconf import DictConfig

from inhand_exp.task.goal_task import GoalTask
from inhand_exp.task.goals import TRAIN_GROUPS, elongated, sample_pair, with_lone_down
from inhand_exp.task.scene import build_scene


def draw_times(cfg: DictConfig, pairs: int, seed: int, raw_steps_per_s: float) -> dict:
    """Mean wall time (ms) per training pair of each group over ``pairs`` draws each, and how
    many physics steps bare ``stepSimulation`` takes in that time (``raw_steps_per_s``, measured
    in the same run): what one reset costs in simulated time forgone."""
    scene = build_scene(cfg)
    task = GoalTask.from_config(scene, cfg)
    tol = (scene.rules.success_tol_m, scene.rules.success_tol_rad)
    ms, flips, low = {}, {}, {}
    for group in TRAIN_GROUPS:
        if group == "lone" and not elongated(scene.model):
            continue  # only a pole has a lone finger
        rng = np.random.default_rng([seed, TRAIN_GROUPS.index(group)])
        t = time.perf_counter()
        drawn = [sample_pair(scene.model, group, rng, scene.workspace, task.hard_posture, tol,
                             start=task.start, fingers=task.fingers) for _ in range(pairs)]
        ms[group] = 1e3 * (time.perf_counter() - t) / pairs
        flips[group] = sum(p.needs_flip for p in drawn)
        low[group] = sum(with_lone_down(scene.model, p).lone_down for p in drawn)
    print(f"stepSimulation alone: {raw_steps_per_s:10.0f} steps/s (same run)")
    for group, v in ms.items():
        print(f"{group:7s} {v:8.1f} ms per pair  ({v * 1e-3 * raw_steps_per_s:8.0f} physics steps; "
              f"{flips[group]} of {pairs} need a flip, {low[group]} the lone finger lower)")
    return {"pairs": pairs, "ms_per_pair": ms, "needs_flip": flips, "lone_down": low,
            "raw_steps_per_s": raw_steps_per_s}
