"""One run of ``inhand-exp``: train and/or evaluate as ``cfg.mode`` says, logging through callbacks.

The learners and the evaluator report through callbacks; this module is where those callbacks
meet the run log, the terminal and the files of the run directory (``policy.pt``, ``goals.csv``).
"""

from __future__ import annotations

import csv
import importlib.resources
import math
import time
from collections.abc import Callable
from pathlib import Path

from omegaconf import DictConfig

from inhand_exp.control.hand import HandModel
from inhand_exp.envs.primitive_env import PrimitiveEnv
from inhand_exp.envs.specs import OBS_DIM
from inhand_exp.learn.evaluate import evaluate
from inhand_exp.learn.ppo import PPO, PPOParams
from inhand_exp.record import RunLog
from inhand_exp.task.goals import goal_set, load_goals, save_goals


def run_job(cfg: DictConfig, run_dir: Path, log: RunLog,
            say: Callable[[str], None] = print) -> dict[str, float] | None:
    """Train and/or evaluate; returns the evaluation summary when there is one."""
    mode = str(cfg.mode.value if hasattr(cfg.mode, "value") else cfg.mode)
    env = PrimitiveEnv(cfg, seed=cfg.seed)
    ppo = PPO(OBS_DIM, len(env.actions), PPOParams.from_config(cfg.learner))
    if cfg.checkpoint:
        ppo.load(Path(cfg.checkpoint))
    if mode in ("train", "train_eval"):
        _train(cfg, env, ppo, run_dir, log, say)
    if mode in ("eval", "train_eval"):
        return _evaluate(cfg, ppo, run_dir, log, say)
    return None


def _train(cfg, env, ppo: PPO, run_dir: Path, log: RunLog, say) -> None:
    start, frames0 = time.perf_counter(), ppo.frames

    def progress(iteration: int, m: dict[str, float]) -> None:
        wall = time.perf_counter() - start
        rate = (m["frames"] - frames0) / wall if wall > 0 else 0.0
        log.write("/train/iteration", {
            "iteration": iteration, "frames": int(m["frames"]), "wall_s": wall,
            "losses": {k: m[k] for k in ("loss_objective", "loss_critic", "loss_entropy")},
            "mean_return": m["mean_reward"], "success_rate": m["success_rate"],
            "drop_rate": m["drop_rate"], "actions_per_s": rate})
        log.flush()
        left = (cfg.train.frames - (m["frames"] - frames0)) / rate if rate > 0 else math.nan
        say(f"iteration {iteration:4d}  frames {int(m['frames']):7d}  success "
            f"{m['success_rate']:5.1%}  drops {m['drop_rate']:5.1%}  {rate:5.1f} actions/s  "
            f"ETA {left / 60:5.1f} min")

    ppo.train(env, cfg.train.frames, progress, checkpoint=run_dir / "policy.pt",
              checkpoint_every=cfg.train.checkpoint_every)
    say(f"policy saved to {run_dir / 'policy.pt'}")


def _evaluate(cfg, ppo: PPO, run_dir: Path, log: RunLog, say) -> dict[str, float]:
    if cfg.eval.goals_file:
        goals = load_goals(cfg.eval.goals_file)
    else:
        model = HandModel.from_config(cfg.hand, cfg.object, cfg.sim.gravity_mps2)
        goals = goal_set(model, cfg.goals.name, cfg.eval.episodes, cfg.goals.seed)
    save_goals(goals, run_dir / "goals.csv")
    env = PrimitiveEnv(cfg, goals=goals, seed=cfg.seed + 1)
    labels = {"object": cfg.object.name, "perturb": cfg.perturb.name, "noise": cfg.noise.name,
              "learner": cfg.learner.name, "seed": int(cfg.seed)}
    summary = evaluate(env, ppo.actor, len(goals),
                       on_episode=lambda r: log.write("/eval/episode", {**r, **labels}))
    say(table(summary, cfg))
    return summary


def paper_row(cfg) -> dict[str, str] | None:
    """The paper's Table II/III cell for this setting, if it has one."""
    text = importlib.resources.files("inhand_exp").joinpath("paper_results.csv").read_text()
    for row in csv.DictReader(text.splitlines()):
        if (row["method"], row["group"], row["object"], row["perturb"], row["noise"]) == (
                cfg.learner.name, cfg.goals.name, cfg.object.name, cfg.perturb.name,
                cfg.noise.name):
            return row
    return None


def table(summary: dict[str, float], cfg) -> str:
    """The evaluation beside the paper's numbers for the same setting."""
    paper = paper_row(cfg)

    def cell(key: str, fmt: str) -> str:
        if paper is None or not paper.get(key):
            return "-"
        return format(float(paper[key]), fmt)

    head = f"{cfg.learner.name} {cfg.goals.name} {cfg.object.name} perturb={cfg.perturb.name} " \
           f"noise={cfg.noise.name}, {summary['episodes']} episodes"
    return "\n".join([
        head,
        f"{'':14s}{'ours':>10s}{'paper':>10s}",
        f"{'success':14s}{summary['success_rate']:10.1%}{cell('success_rate', '10.1%')}",
        f"{'drop':14s}{summary['drop_rate']:10.1%}{cell('drop_rate', '10.1%')}",
        f"{'timeout':14s}{summary['timeout_rate']:10.1%}{'-':>10s}",
        f"{'avg time (s)':14s}{summary['avg_time_s']:10.2f}{cell('avg_time_s', '10.2f')}"])
