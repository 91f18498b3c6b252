"""One run of ``inhand-exp``: train and/or evaluate as ``cfg.mode`` says, logging through callbacks.

The learners and the evaluator report through callbacks; this module is where those callbacks
meet the run log, the terminal and the files of the run directory (``policy.pt``, ``goals.csv``).
"""

from __future__ import annotations

import csv
import fcntl
import hashlib
import importlib.resources
import json
import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from inhand_exp import policies
from inhand_exp.config import ConfigError, TaskConfig
from inhand_exp.control.hand import HandModel
from inhand_exp.control.sample import Workspace
from inhand_exp.envs.batched import batched_env
from inhand_exp.learn.demonstrations import DemoRecorder
from inhand_exp.learn.evaluate import evaluate
from inhand_exp.learn.registry import Learner, make_learner
from inhand_exp.progress import ProgressBar
from inhand_exp.record import RunLog
from inhand_exp.record.scene import SceneGeometry, SceneReplay
from inhand_exp.runinfo import merged, unlike_training
from inhand_exp.task.actions import action_table, flip_actions
from inhand_exp.task.goals import (
    GoalPair,
    GoalsError,
    goal_set,
    load_goals,
    reach_fingers,
    save_goals,
    settable,
    start_of,
)
from inhand_exp.task.scene import true_object

CHECKPOINT = "policy.pt"
PACKAGED = f"{policies.DEMO}.pt"  # in inhand_exp/policies/: what mode=demo shows
DEMO_GROUPS = ("easy", "medium", "hard")


def packaged_policy() -> Path:
    return policies.packaged(policies.DEMO)


def derived_seed(seed: int, *stream: int) -> int:
    """A seed for one stream of a run (training envs after an iteration, evaluation...)."""
    return int(np.random.SeedSequence([seed, *stream]).generate_state(1)[0])


@dataclass
class Job:
    """What a run will do, checked before anything is written: the learner, loaded from its
    checkpoint when there is one, its frame budget, and the goal file's pairs when given."""

    mode: str
    learner: Learner | None = None
    target: int = 0
    goals: list[GoalPair] | None = None
    resumed: bool = False


def prepare(cfg: DictConfig, run_dir: Path, overrides: Iterable[str] = ()) -> Job:
    """Build the learner and read every input (checkpoint, goal file): a bad one is refused
    here, with a ``ConfigError``, ``CheckpointError``, ``GoalsError`` or ``FileNotFoundError``,
    before the run writes anything.

    ``resume``: continue the training whose checkpoint is in ``run_dir`` up to ``train.frames``
    in all; otherwise a ``checkpoint`` is a starting point for ``train.frames`` more. A run that
    trains records its ``overrides`` (the command line's) in the policy it saves, after those of
    the checkpoint it started from.
    """
    mode = str(getattr(cfg.mode, "value", cfg.mode))
    if cfg.goals.x0 is not None:  # a fixed start the hand cannot hold: refused before any run
        start_of(HandModel.from_config(cfg.hand, cfg.object, cfg.sim.gravity_mps2), cfg.goals)
    if mode == "goals":
        return Job(mode)
    # the networks' initial weights and the actions sampled in training come from torch's
    # generator: seeded from the run's seed (a checkpoint then restores its own state)
    torch.manual_seed(derived_seed(cfg.seed, 3))
    learner = make_learner(cfg)
    target = cfg.train.frames
    if cfg.resume:
        learner.load(run_dir / CHECKPOINT)
        if mode == "train" and learner.frames >= target:
            raise ConfigError(f"resume={run_dir}: the training is finished ({learner.frames} of "
                              f"train.frames={target} frames); raise train.frames to go on")
    elif cfg.checkpoint:
        learner.load(Path(cfg.checkpoint))
        target += learner.frames
    elif mode == "demo":
        learner.load(packaged_policy())
    if mode in ("train", "train_eval"):
        learner.trained_with = merged(learner.trained_with or [], overrides)
    goals = None
    if mode in ("eval", "train_eval") and cfg.eval.goals_file:
        goals = test_goals(cfg)
    return Job(mode, learner, target, goals, resumed=bool(cfg.resume))


def run_job(cfg: DictConfig, run_dir: Path, log: RunLog, job: Job | None = None,
            say: Callable[[str], None] = print) -> dict[str, float] | None:
    """Train and/or evaluate as ``job`` (``prepare``) says; returns the evaluation summary when
    there is one."""
    job = job or prepare(cfg, run_dir)
    if job.mode == "goals":
        write_goal_set(cfg, run_dir, say)
        return None
    learner = job.learner
    if job.mode == "demo":
        return _demo(cfg, learner, run_dir, log, say)
    if job.resumed:
        say(f"resuming from {run_dir / CHECKPOINT}: iteration {learner.iteration}, "
            f"{learner.frames} frames")
    if job.mode in ("train", "train_eval"):
        if cfg.train.store and not job.resumed:
            _train_shared(cfg, learner, job.target, log, say)
        else:
            _train(cfg, learner, job.target, run_dir, log, say)
    if job.mode in ("eval", "train_eval"):
        if job.mode == "eval":
            _note_unlike_training(cfg, learner, say)
        return _evaluate(cfg, learner, run_dir, log, say, job.goals)
    return None


def _note_unlike_training(cfg, learner: Learner, say) -> None:
    """Say which task settings of the policy's training this evaluation does not use."""
    unlike = unlike_training(cfg, learner.trained_with)
    if unlike:
        say(f"note: the policy was trained with {', '.join(unlike)}; add the same overrides "
            f"to evaluate it as it was trained")


# Goal settings that shape only the test set. They stay out of a policy's store key, so that
# setting them (or adding such a setting) does not orphan the policies already stored.
TEST_ONLY_GOAL_KEYS = ("name", "test_pairs", "hard_flip_share")


def policy_key(cfg: DictConfig) -> str:
    """The name of this run's policy in ``train.store``: learner, object, noise and seed, and a
    digest of everything else that shapes the policy (the task, the training goals, the
    learner's settings, the budget), but not what only the evaluation uses (the goal group
    tested, the perturbation of the simulated object, ``eval.*``, ``log.*``)."""
    c = OmegaConf.to_container(cfg, resolve=True, enum_to_str=True)
    for key in ("perturb", "eval", "log", "mode", "checkpoint", "resume"):
        c.pop(key, None)
    c["goals"] = {k: v for k, v in c["goals"].items() if k not in TEST_ONLY_GOAL_KEYS}
    if not c["goals"]["train_groups"]:
        c["goals"]["train_groups"] = [cfg.goals.name]  # it trains on the tested group
    c["train"] = {k: c["train"][k] for k in ("frames", "num_envs")}
    c["task"] = _unlike_defaults(c["task"], TaskConfig)
    digest = hashlib.sha256(json.dumps(c, sort_keys=True).encode()).hexdigest()[:10]
    return f"{cfg.learner.name}-{cfg.object.name}-noise_{cfg.noise.name}-seed{cfg.seed}-{digest}"


def _unlike_defaults(section: dict, schema: type) -> dict:
    """``section`` without the settings at their schema default: a task option added later,
    at its default, leaves the keys of the policies already stored as they were."""
    defaults = OmegaConf.to_container(OmegaConf.structured(schema), enum_to_str=True)
    return {k: v for k, v in section.items() if k not in defaults or defaults[k] != v}


def _train_shared(cfg, learner: Learner, target: int, log: RunLog, say) -> None:
    """Train in ``train.store/<policy_key>``, once for every run that needs that policy: the
    first run to get there trains (or continues an interrupted training) while holding the
    store's lock; the others wait for it, then load its policy."""
    store = Path(cfg.train.store) / policy_key(cfg)
    store.mkdir(parents=True, exist_ok=True)
    with open(store.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if (store / CHECKPOINT).is_file():
            mine = learner.trained_with
            learner.load(store / CHECKPOINT)
            learner.trained_with = learner.trained_with or mine  # one written before they were
        if learner.frames >= target:
            say(f"reusing the policy in {store} ({learner.frames} frames)")
            return
        if not learner.frames:
            say(f"no policy stored in {store} yet: training it")
        _train(cfg, learner, target, store, log, say)


def _train(cfg, learner: Learner, target: int, run_dir: Path, log: RunLog, say) -> None:
    left = target - learner.frames
    if left <= 0:
        say(f"training already has {learner.frames} of train.frames={target} frames")
        return
    start, frames0 = time.perf_counter(), learner.frames
    bar = ProgressBar(target, "frames", start=frames0, enabled=cfg.log.progress)

    spent = [0.0, 0.0]  # collecting, learning (s)

    def progress(iteration: int, m: dict[str, float]) -> None:
        wall = time.perf_counter() - start
        log.write("/train/iteration", {
            "iteration": iteration, "frames": int(m["frames"]), "wall_s": wall,
            "losses": {k: v for k, v in m.items() if k.startswith("loss_")},
            "mean_return": m["mean_reward"], "success_rate": m["success_rate"],
            "drop_rate": m["drop_rate"], "actions_per_s": bar.rate(int(m["frames"])),
            "collect_s": m["collect_s"], "learn_s": m["learn_s"]})
        spent[0] += m["collect_s"]
        spent[1] += m["learn_s"]
        log.flush()
        bar.update(int(m["frames"]), f"it {iteration}  success {m['success_rate']:5.1%}  "
                                     f"drops {m['drop_rate']:5.1%}")

    env = batched_env(cfg, derived_seed(cfg.seed, 0, learner.iteration),
                      env_class=learner.env_class)
    try:
        learner.train(env, left, progress, checkpoint=run_dir / CHECKPOINT,
                      checkpoint_every=cfg.train.checkpoint_every)
    finally:
        bar.close()
        if not env.is_closed:  # the collector closes it when it ends
            env.close()
    wall = time.perf_counter() - start
    say(f"policy saved to {run_dir / CHECKPOINT} ({learner.frames} frames, {wall:.0f} s: "
        f"collecting {spent[0]:.0f} s, learning {spent[1]:.0f} s = {spent[1] / wall:.1%})")


def test_goals(cfg) -> list[GoalPair]:
    """The evaluation's goal set: ``eval.goals_file``, or the first ``eval.episodes`` test
    pairs of the ``goals`` group.

    Pairs are drawn on the nominal object. When ``perturb`` changes the simulated object's
    shape, a pair whose grasp does not fit it at X0 is drawn again (a drawn set) or refused
    (a goal file), since the episode could not start."""
    model = HandModel.from_config(cfg.hand, cfg.object, cfg.sim.gravity_mps2)
    fits = None
    if cfg.perturb.width_scale != 1 or cfg.perturb.length_scale != 1:
        fits = settable(HandModel.from_config(cfg.hand, true_object(cfg.object, cfg.perturb),
                                              cfg.sim.gravity_mps2))
    if cfg.eval.goals_file:
        goals = load_goals(cfg.eval.goals_file, model)
        bad = [i for i, pair in enumerate(goals) if not fits(pair)] if fits else []
        if bad:
            raise GoalsError(f"{cfg.eval.goals_file}: the grasp of pair(s) "
                             f"{', '.join(map(str, bad[:5]))}{' ...' if len(bad) > 5 else ''} "
                             f"does not fit the simulated object (perturb={cfg.perturb.name}) "
                             f"at X0, so those episodes cannot start")
        return goals
    return goal_set(model, cfg.goals.name, cfg.eval.episodes, cfg.goals.seed, cfg.eval.split,
                    workspace=Workspace.from_config(cfg.task),
                    hard_posture=cfg.goals.hard_goal_posture, start=start_of(model, cfg.goals),
                    fits=fits, fingers=reach_fingers(model, cfg),
                    flip_share=cfg.goals.hard_flip_share)


def write_goal_set(cfg, run_dir: Path, say) -> Path:
    """``mode=goals``: the test set alone, to share or to feed another learner."""
    goals = test_goals(cfg)
    path = save_goals(goals, run_dir / "goals.csv")
    flips, low = sum(p.needs_flip for p in goals), sum(p.lone_down for p in goals)
    say(f"{len(goals)} {cfg.goals.name} pairs written to {path}; {flips} "
        f"({flips / len(goals):.1%}) need a flip, {low} ({low / len(goals):.1%}) need the lone "
        f"finger lower on the pole")
    return path


def _demo(cfg, learner: Learner, run_dir: Path, log: RunLog, say) -> dict[str, float]:
    """``mode=demo``: the policy on the first ``eval.episodes`` test pairs of each group, with
    the states of the last group's episodes recorded (for ``inhand-render``)."""
    if not cfg.checkpoint:
        which = (f"the packaged Table II policy ({PACKAGED}: PPO, seed 0, "
                 f"{learner.frames:,} frames of the README recipe)")
    elif Path(cfg.checkpoint).parent == packaged_policy().parent:
        which = (f"the packaged policy {Path(cfg.checkpoint).stem} ({learner.frames:,} frames; "
                 f"its recipe: src/inhand_exp/policies/README.md)")
    else:
        which = cfg.checkpoint
    say(f"inhand-exp demo: {which}, evaluated on the first {cfg.eval.episodes} test pairs of "
        f"each goal group ({', '.join(DEMO_GROUPS)}). The README's Table II uses 500 pairs "
        f"per group. To train a policy of your own instead: inhand-exp mode=train_eval "
        f"train.frames=163840 'goals.train_groups=[easy,medium,hard]' task.reward_progress=0.1")
    _note_unlike_training(cfg, learner, say)
    out = {}
    for group in DEMO_GROUPS:
        sub = cfg.copy()
        sub.goals.name = group
        if group != DEMO_GROUPS[-1]:
            sub.log.sim_state_hz = 0.0
        summary = _evaluate(sub, learner, run_dir, log, say, goals_file=f"goals-{group}.csv")
        out.update({f"{group}_{k}": v for k, v in summary.items()})
    return out


def _evaluate(cfg, learner: Learner, run_dir: Path, log: RunLog, say,
              goals: list[GoalPair] | None = None, goals_file: str = "goals.csv"
              ) -> dict[str, float]:
    goals = goals if goals is not None else test_goals(cfg)
    save_goals(goals, run_dir / goals_file)
    labels = {"object": cfg.object.name, "perturb": cfg.perturb.name, "noise": cfg.noise.name,
              "learner": cfg.learner.name, "seed": int(cfg.seed)}
    bar = ProgressBar(len(goals), "episodes", enabled=cfg.log.progress)
    results = []
    scene = SceneReplay(log.write, SceneGeometry.from_config(cfg), cfg.log.scene_episodes,
                        time.time_ns())

    demos = DemoRecorder() if cfg.eval.demonstrations else None

    def on_episode(rec: dict) -> None:
        log.write("/eval/episode", {**rec, **labels})
        if demos is not None:
            demos.end(rec)
        scene.on_episode(rec)
        results.append(rec["success"])
        bar.update(len(results), f"success {np.mean(results):5.1%}")

    def on_state(rec: dict) -> None:
        log.write("/sim/state", rec)
        scene.on_state(rec)

    torch.manual_seed(derived_seed(cfg.seed, 2))  # eval.sample draws from torch's generator
    env = batched_env(cfg, derived_seed(cfg.seed, 1), goals=goals,
                      num_envs=min(cfg.train.num_envs, len(goals)),
                      states_hz=cfg.log.sim_state_hz, once=True, env_class=learner.env_class)
    def on_action(rec: dict) -> None:
        log.write("/episode/action", rec)

    actions = action_table(cfg.primitives) if learner.per_action_log else None
    try:
        summary = evaluate(env, learner.policy, goals, on_episode=on_episode,
                           on_action=on_action if actions else None,
                           on_state=on_state,
                           action_names=[a.name for a in actions] if actions else None,
                           sample=cfg.eval.sample,
                           flip_actions=flip_actions(actions) if actions else None,
                           on_step=demos.step if demos is not None else None)
    finally:
        bar.close()
        env.close()
    if demos is not None:
        name = Path(goals_file).stem.replace("goals", "demonstrations", 1) + ".pt"
        path = demos.save(run_dir / name, {
            "learner": str(cfg.learner.name), "goals": str(cfg.goals.name),
            "split": str(cfg.eval.split), "task": OmegaConf.to_container(cfg.task, resolve=True,
                                           enum_to_str=True)})
        n, won = len(demos.outcome), sum(success for success, _ in demos.outcome.values())
        say(f"demonstrations: {n} episode{'s' * (n != 1)}, {won} successful, written to {path}")
    say(table(summary, cfg, sampled=cfg.eval.sample and learner.stochastic))
    return summary


def paper_row(cfg) -> dict[str, str] | None:
    """The paper's Table II/III cell for this setting, if it has one."""
    text = importlib.resources.files("inhand_exp").joinpath("paper_results.csv").read_text()
    rows = list(csv.DictReader(text.splitlines()))
    # the cube study's goals are "any reachable pose" (group "any" in the paper's table)
    for group in (cfg.goals.name, "any"):
        for row in rows:
            if (row["method"], row["group"], row["object"], row["perturb"], row["noise"]) == (
                    cfg.learner.name, group, cfg.object.name, cfg.perturb.name,
                    cfg.noise.name):
                return row
    return None


def _seconds(value: float) -> str:
    """A mean time, or '-' when there is none (no successful episode)."""
    return f"{value:10.2f}" if math.isfinite(value) else f"{'-':>10s}"


def _flipped(summary: dict[str, float], prefix: str) -> str:
    """"; flipped in N (M solved)" for a subset whose episodes counted their flips."""
    if f"{prefix}flipped" not in summary:
        return ""
    return (f"; flipped in {summary[f'{prefix}flipped']} "
            f"({summary[f'{prefix}flipped_success']} solved)")


def table(summary: dict[str, float], cfg, sampled: bool) -> str:
    """The evaluation beside the paper's numbers for the same setting; ``sampled``: the
    policy drew its actions (else it acted deterministically)."""
    paper = paper_row(cfg)

    def cell(key: str, fmt: str) -> str:
        if paper is None or not paper.get(key):
            return f"{'-':>10s}"
        return format(float(paper[key]), fmt)

    how = "sampled" if sampled else "deterministic"
    head = f"{cfg.learner.name} {cfg.goals.name} {cfg.object.name} perturb={cfg.perturb.name} " \
           f"noise={cfg.noise.name}, {summary['episodes']} episodes, {how} actions" \
           + (" (training pairs, not the paper's test set)"
              if cfg.eval.split == "train" else "")
    flips = [f"{label:14s}{summary[f'{flag}_success_rate']:10.1%}{'-':>10s}"
             f"   ({summary[flag]} episodes; drops {summary[f'{flag}_drop_rate']:.1%}"
             f"{_flipped(summary, f'{flag}_')})"
             for flag, label in (("needs_flip", "needs a flip"), ("no_flip", "no flip needed"),
                                 ("lone_down", "lone down"))
             if summary.get(flag)]
    if summary.get("flipped"):
        flips.append(f"flipped in {summary['flipped']} of the {summary['episodes']} episodes, "
                     f"{summary['flipped_success']} of them solved")
    return "\n".join([
        head,
        f"{'':14s}{'ours':>10s}{'paper':>10s}",
        f"{'success':14s}{summary['success_rate']:10.1%}{cell('success_rate', '10.1%')}",
        f"{'drop':14s}{summary['drop_rate']:10.1%}{cell('drop_rate', '10.1%')}",
        f"{'timeout':14s}{summary['timeout_rate']:10.1%}{'-':>10s}",
        f"{'avg time (s)':14s}{_seconds(summary['avg_time_s'])}{cell('avg_time_s', '10.2f')}",
        *flips])
