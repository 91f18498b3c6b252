"""Which test goals of the cube the action set reaches from the study's start (``task.reach``).

The run's own goal set (the first ``pairs`` test pairs of its ``goals`` group, from the one
start ``goals.x0``) is split into the goals the start's posture holds and the ones only another
posture holds; for each, how many goal cells the breadth-first search over reposes, releases
and lands reaches (``opposite_only``: were only pairs on opposite faces allowed to carry the
cube, see ``task.reach``). With ``run`` (a directory of evaluation logs of that goal set) the
episodes' success and drop rates are split the same way.
"""

from __future__ import annotations

import time

from omegaconf import DictConfig

from inhand_exp.config import ConfigError
from inhand_exp.control.sample import Workspace
from inhand_exp.experiment import test_goals
from inhand_exp.task.reach import Reach
from inhand_exp.task.scene import build_scene


def goal_reach(cfg: DictConfig, pairs: int, resolution_m: float = 0.02,
               resolution_rad: float = 0.1, run: str | None = None,
               opposite_only: bool = False) -> dict:
    """The figures as a dict; prints a summary."""
    if cfg.goals.get("x0") is None:
        raise ConfigError("inhand-bench reach searches from one start: set goals.x0 "
                          "(as sweeps/cube.yaml does)")
    if not cfg.primitives.release_land or cfg.primitives.slide or cfg.primitives.flip:
        raise ConfigError("inhand-bench reach models reposes, releases and lands only "
                          "(primitives=cube)")
    scene = build_scene(cfg)
    cfg.eval.episodes = pairs
    goals = test_goals(cfg)
    ws = Workspace.from_config(cfg.task)
    x0, start = goals[0].x0, goals[0].contacts
    reach = Reach.lattice(scene.model, cfg.primitives, x0[0], (ws.low[1], ws.high[1]),
                          (ws.low[2], ws.high[2]), resolution_m, resolution_rad,
                          opposite_only=opposite_only)
    t = time.perf_counter()
    reach.search(x0, start)
    build_s = time.perf_counter() - t
    split = {"same posture": [p for p in goals if not p.needs_flip],
             "other posture": [p for p in goals if p.needs_flip]}
    hit = {k: sum(reach.goal_reached(p.xg) for p in v) for k, v in split.items()}
    lo, hi = reach.angles()
    three = sum(lifted < 0 for _, lifted, _, _ in reach.reached)
    rule = "opposite faces only" if opposite_only else "any two faces whose forces hold it"
    print(f"pairs carry the object from {rule}")
    print(f"lattice {len(reach.zs)} heights x {len(reach.ts)} angles at x = {x0[0]:.3f} m "
          f"({resolution_m} m, {resolution_rad} rad); {len(reach.reached)} states reached "
          f"({three} with three fingers) in {build_s:.1f} s, angles {lo:+.2f} to {hi:+.2f} rad")
    for k, v in split.items():
        print(f"{k:14s} {len(v):4d} goals, {hit[k]:4d} reached")
    out = {"pairs": len(goals), "opposite_only": opposite_only, "states": len(reach.reached),
           "three_finger_states": three, "build_s": build_s, "angles_rad": [lo, hi],
           "goals": {k: len(v) for k, v in split.items()}, "reached": hit}
    if run is not None:
        out["episodes"] = _episodes_split(run, goals, reach)
    return out


def _episodes_split(run: str, goals, reach: Reach) -> dict:
    """Success and drop rates of the run's episodes on these goals, reached or not."""
    from inhand_exp.analysis.frames import load

    eps = load([run]).episodes
    eps = eps[eps["episode"] < len(goals)]
    if eps.empty:
        raise ConfigError(f"{run}: no evaluation episode of these {len(goals)} goals")
    reached = {i: reach.goal_reached(goals[i].xg) for i in range(len(goals))}
    eps = eps.assign(reached=eps["episode"].map(reached))
    out = {}
    for flag, rows in eps.groupby("reached"):
        key = "reached" if flag else "not reached"
        out[key] = {"episodes": len(rows), "success_rate": float(rows["success"].mean()),
                    "drop_rate": float(rows["dropped"].mean())}
        print(f"episodes, goal {key:11s} {len(rows):4d}: success {rows['success'].mean():6.1%}, "
              f"drops {rows['dropped'].mean():6.1%}")
    return out
