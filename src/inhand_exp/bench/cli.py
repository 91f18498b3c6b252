"""``inhand-bench``: speed of the control loop and success of the primitives; last line is JSON.

    inhand-bench speed [--object pole|cube] [--seconds S] [overrides...]
    inhand-bench primitives [--object pole|cube] [--trials N] [--seed S] [--workers W]
                            [--only hold,repose,...,perturbed] [--perturbations thinner,...]
                            [overrides...]
    inhand-bench env [--workers W] [--steps N] [--seed S] [overrides...]
    inhand-bench graph [learner.resolution_m=M learner.resolution_rad=R ...]
    inhand-bench flips [--trials N] [--seed S] [overrides...]
    inhand-bench load [--minutes M] [--workers W] [overrides...]
    inhand-bench torques [--trials N] [--actions N] [--seed S] [overrides...]
    inhand-bench goals [--pairs N] [--seed S] [overrides...]
    inhand-bench reach --object cube [--pairs N] [--run EVAL_DIR] [--opposite-only]
                       [--resolution-m M] [--resolution-rad R] [overrides...]
    inhand-bench fingerprint [--actions N] [--seed S] [--out RUN.npz] [--against RUN.npz]
                             [overrides...]

Overrides are Hydra overrides of the project config (e.g. ``sim.timestep_s=0.002``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import zlib
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from functools import partial
from pathlib import Path

import numpy as np
from hydra import compose, initialize_config_dir
from hydra.errors import ConfigCompositionException
from omegaconf import DictConfig

from inhand_exp.bench import trials
from inhand_exp.cli import CONF_DIR
from inhand_exp.config import ConfigError, PerturbConfig, validate

# Trials per section when --trials is not given: the targets of the physics milestone.
DEFAULT_TRIALS = {"hold": 100, "repose": 1000, "slide": 500, "flip_left": 200,
                  "flip_right": 200, "flip_left_tilted": 10, "flip_right_tilted": 10,
                  "perturbed": 200, "perturbed_flip": 50, "release": 200, "land": 200,
                  "land_other_elbow": 200}
# What the perturbed section runs on each perturbed pole and under noise: every primitive the
# pole's mid level uses (the controllers keep the nominal model).
PERTURBED_PRIMITIVES = ("repose", "slide", "flip_left", "flip_right")
TILTED_RAD = 1.0  # the flip_*_tilted sections start from |theta| >= this
PERTURBATIONS = {"heavier": dict(mass_scale=1.1), "lighter": dict(mass_scale=0.9),
                 "thicker": dict(width_scale=1.5), "thinner": dict(width_scale=0.5),
                 "longer": dict(length_scale=1.1), "shorter": dict(length_scale=0.9)}


def load_config(obj: str, overrides: list[str]) -> DictConfig:
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[f"object={obj}", *overrides])
    validate(cfg)
    return cfg


# --- primitives ---------------------------------------------------------------------------

_BENCHES: dict[tuple, trials.Bench] = {}


def _run_trial(cfg: DictConfig, setting: tuple, name: str, seed: int, index: int
               ) -> trials.Trial | None:
    """One trial in this process (worlds are built once per process and setting)."""
    if setting not in _BENCHES:
        perturb, noise = setting
        p = PerturbConfig(name=perturb, **PERTURBATIONS.get(perturb, {}))
        _BENCHES[setting] = trials.Bench(cfg, p, noise)
    bench = _BENCHES[setting]
    rng = np.random.default_rng([seed, zlib.crc32(f"{name}/{setting}".encode()), index])
    fn: Callable = {"hold": trials.hold, "repose": trials.repose, "slide": trials.slide,
                    "flip_left": partial(trials.flip, finger=0),
                    "flip_right": partial(trials.flip, finger=2),
                    "flip_left_tilted": partial(trials.flip, finger=0, min_tilt=TILTED_RAD),
                    "flip_right_tilted": partial(trials.flip, finger=2, min_tilt=TILTED_RAD),
                    "release": trials.release, "land": trials.land,
                    "land_other_elbow": partial(trials.land, other_elbow=True)}[name]
    return fn(bench, rng)


def summarise(results: list[trials.Trial | None]) -> dict:
    done = [r for r in results if r is not None]
    if not done:
        return {"trials": 0, "success_rate": None, "drop_rate": None}
    em = np.array([r.err_m for r in done])
    er = np.array([r.err_rad for r in done])
    return {"trials": len(done),
            "success_rate": float(np.mean([r.success for r in done])),
            "drop_rate": float(np.mean([r.dropped for r in done])),
            "mean_err_m": float(em.mean()), "max_err_m": float(em.max()),
            "mean_err_rad": float(er.mean()), "max_err_rad": float(er.max()),
            "sim_s": float(sum(r.sim_s for r in done)),
            "wall_s": float(sum(r.wall_s for r in done)),
            "no_feasible_start": len(results) - len(done)}


def run_section(pool, cfg, setting, name, n, seed) -> dict:
    job = partial(_run_trial, cfg, setting, name, seed)
    results = list(pool.map(job, range(n))) if pool else [job(i) for i in range(n)]
    return summarise(results)


def primitives(args, cfg: DictConfig) -> dict:
    names = ["hold", "repose", "slide", "flip_left", "flip_right", "flip_left_tilted",
             "flip_right_tilted"]
    if cfg.object.name == "cube":
        names = ["hold", "repose", "release", "land", "land_other_elbow"]
    only = args.only.split(",") if args.only else names + ["perturbed"]
    count = (lambda s: args.trials) if args.trials else DEFAULT_TRIALS.get
    pool = ProcessPoolExecutor(args.workers) if args.workers > 1 else None
    noise_paper = (0.005, np.deg2rad(2.86))
    out = {"object": cfg.object.name, "seed": args.seed, "results": {}, "perturbed": {}}
    try:
        for name in names:
            if name in only:
                res = run_section(pool, cfg, ("none", (0.0, 0.0)), name, count(name), args.seed)
                out["results"][name] = res
                _print_row(name, res)
        if "perturbed" in only and cfg.object.name == "pole":
            settings = [(p, (0.0, 0.0)) for p in PERTURBATIONS] + [("none", noise_paper)]
            # the primitives named in --only, if any; the settings named in --perturbations
            named = [p for p in PERTURBED_PRIMITIVES if p in only] or PERTURBED_PRIMITIVES
            for setting in settings:
                label = setting[0] if setting[0] != "none" else "noise=paper"
                if args.perturbations and label not in args.perturbations.split(","):
                    continue
                out["perturbed"][label] = {}
                for name in named:
                    n = count("perturbed_flip" if name.startswith("flip") else "perturbed")
                    res = run_section(pool, cfg, setting, name, n, args.seed)
                    out["perturbed"][label][name] = res
                    _print_row(f"{name} {label}", res)
    finally:
        if pool:
            pool.shutdown()
    return out


def _print_row(name: str, r: dict) -> None:
    if not r["trials"]:
        print(f"{name:22s} no feasible start found", flush=True)
        return
    print(f"{name:22s} n={r['trials']:5d}  success {r['success_rate']:6.1%}  "
          f"drop {r['drop_rate']:5.1%}  err mean/max {r['mean_err_m'] * 1e3:5.2f}/"
          f"{r['max_err_m'] * 1e3:5.2f} mm {r['mean_err_rad']:.4f}/{r['max_err_rad']:.4f} rad  "
          f"sim {r['sim_s']:7.1f} s  wall {r['wall_s']:6.1f} s", flush=True)


# --- speed --------------------------------------------------------------------------------

def hold_rates(cfg: DictConfig, seconds: float, seed: int) -> tuple[float, float]:
    """(raw stepSimulation, full control loop) physics steps/s, measured in the same runs of a
    hold."""
    bench = trials.Bench(cfg)
    rng = np.random.default_rng(seed)
    world = bench.world
    loop_steps, loop_wall, raw_wall = 0, 0.0, 0.0
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline:
        contacts = bench.start(rng)
        prim = trials.Repose(bench.model, contacts, np.zeros(3), 2.0, bench.prim)
        world.step_wall_s = 0.0
        t = time.perf_counter()
        out = trials.execute(world, prim)
        loop_wall += time.perf_counter() - t
        loop_steps += out.steps * world.substeps
        raw_wall += world.step_wall_s
    return loop_steps / raw_wall, loop_steps / loop_wall


def speed(args, cfg: DictConfig) -> dict:
    """Control-loop and raw stepSimulation rates, and the wall time of each primitive."""
    raw, loop = hold_rates(cfg, args.seconds, args.seed)
    ms = {}
    for name in ("repose", "slide", "flip_left", "flip_right"):
        runs = [r for r in (_run_trial(cfg, ("none", (0.0, 0.0)), name, args.seed, i)
                            for i in range(args.primitive_runs)) if r is not None]
        if runs:
            ms[name] = 1e3 * float(np.mean([r.wall_s for r in runs]))
    print(f"stepSimulation alone: {raw:10.0f} steps/s  (inside the loop, same run)")
    print(f"full control loop:    {loop:10.0f} steps/s  ratio {loop / raw:.1%}")
    for name, v in ms.items():
        print(f"wall per {name:11s} {v:8.1f} ms")
    return {"object": cfg.object.name, "raw_steps_per_s": raw, "loop_steps_per_s": loop,
            "ratio": loop / raw, "ms_per_primitive": ms}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="inhand-bench", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("what", choices=("speed", "primitives", "env", "graph", "load",
                                         "flips", "torques", "goals", "reach",
                                         "fingerprint"))
    parser.add_argument("--minutes", type=float, default=30.0, help="load: how long")
    parser.add_argument("--object", choices=("pole", "cube"), default="pole")
    parser.add_argument("--trials", type=int, default=None,
                        help="trials per section (default: the milestone's counts)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=1, help="worker processes")
    parser.add_argument("--steps", type=int, default=8,
                        help="env: steps of the whole batch (train.num_envs actions each)")
    parser.add_argument("--actions", type=int, default=200,
                        help="torques: random mid-level actions whose torques are recorded; "
                             "fingerprint: random allowed actions played")
    parser.add_argument("--only", default="", help="comma-separated sections")
    parser.add_argument("--perturbations", default="",
                        help="primitives: the perturbed section's settings, comma-separated "
                             f"(default all: {','.join([*PERTURBATIONS, 'noise=paper'])}); "
                             "primitives named in --only restrict its primitives")
    parser.add_argument("--pairs", type=int, default=20,
                        help="goals: pairs drawn per group; reach: test pairs checked")
    parser.add_argument("--run", default=None,
                        help="reach: evaluation logs of the same goals, split by reach")
    parser.add_argument("--opposite-only", action="store_true",
                        help="reach: only two fingers on opposite faces carry the cube")
    parser.add_argument("--resolution-m", type=float, default=0.02,
                        help="reach: the lattice's height step (m)")
    parser.add_argument("--resolution-rad", type=float, default=0.1,
                        help="reach: the lattice's angle step (rad)")
    parser.add_argument("--out", type=Path, default=None,
                        help="fingerprint: keep this run's masks, outcomes and poses (.npz)")
    parser.add_argument("--against", type=Path, default=None,
                        help="fingerprint: compare with a run kept by --out")
    parser.add_argument("--seconds", type=float, default=5.0, help="speed: loop timing budget")
    parser.add_argument("--primitive-runs", type=int, default=5,
                        help="speed: runs per primitive for the wall time")
    parser.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. sim.timestep_s=0.002")
    args = parser.parse_intermixed_args(argv)
    if args.trials is not None and args.trials <= 0:
        parser.error(f"--trials must be > 0, got {args.trials}")
    unknown = set(filter(None, args.perturbations.split(","))) - {*PERTURBATIONS, "noise=paper"}
    if unknown:
        parser.error(f"--perturbations: unknown {', '.join(sorted(unknown))}; known: "
                     f"{', '.join([*PERTURBATIONS, 'noise=paper'])}")
    if args.pairs <= 0:
        parser.error(f"--pairs must be > 0, got {args.pairs}")
    if args.actions <= 0:
        parser.error(f"--actions must be > 0, got {args.actions}")
    if not (args.resolution_m > 0 and args.resolution_rad > 0):
        parser.error("--resolution-m and --resolution-rad must be > 0")
    learner = {"graph": ["learner=search", "mode=eval"],
               "torques": ["learner=ddpg", "mode=train"]}.get(args.what, [])
    try:
        cfg = load_config(args.object, [*learner, *args.overrides])
    except (ConfigError, ConfigCompositionException) as err:
        sys.exit(f"inhand-bench: config error: {err}".splitlines()[0])
    if args.what == "load":
        from inhand_exp.bench.load import load_run

        cfg.train.workers = args.workers
        result = load_run(cfg, args.minutes, every_s=max(5.0, args.minutes * 60 / 60),
                          seed=args.seed)
    elif args.what == "flips":
        from inhand_exp.bench.flips import flip_conditions

        result = flip_conditions(cfg, args.trials or 300, args.seed)
    elif args.what == "torques":
        from inhand_exp.bench.torques import torque_exploration

        result = torque_exploration(cfg, args.trials or 20, args.actions, args.seed)
    elif args.what == "graph":
        from inhand_exp.bench.graph import graph_size

        result = graph_size(cfg, seed=args.seed)
    elif args.what == "goals":
        from inhand_exp.bench.goal_draws import draw_times

        raw, _ = hold_rates(cfg, 2.0, args.seed)
        result = draw_times(cfg, args.pairs, args.seed, raw)
    elif args.what == "reach":
        from inhand_exp.bench.reach import goal_reach

        try:
            result = goal_reach(cfg, args.pairs, args.resolution_m, args.resolution_rad,
                                run=args.run, opposite_only=args.opposite_only)
        except ConfigError as err:
            sys.exit(f"inhand-bench: {err}")
    elif args.what == "fingerprint":
        from inhand_exp.bench.fingerprint import fingerprint

        try:
            result = fingerprint(cfg, args.actions, args.seed, args.out, args.against)
        except ConfigError as err:
            sys.exit(f"inhand-bench: {err}")
    elif args.what == "env":
        from inhand_exp.bench.throughput import env_throughput

        raw, _ = hold_rates(cfg, 2.0, args.seed)
        result = env_throughput(cfg, args.workers, args.steps, args.seed, raw)
    else:
        result = speed(args, cfg) if args.what == "speed" else primitives(args, cfg)
    print(json.dumps(result))
