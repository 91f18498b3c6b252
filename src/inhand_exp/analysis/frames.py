"""Run logs to tidy pandas DataFrames: one row per run, per training iteration, per episode.

Every ``*.mcap`` below the given paths is read with ``record.read_log``, complete or truncated
(a killed run keeps its completed chunks). A file that is not a run log of this project (not
MCAP, or no ``/run/config``) is skipped with a warning naming it; nothing else stops the
reading. A run directory may hold several logs: a resumed training's legs (``run-2.mcap``...)
and the attempts of a job that was interrupted and run again (``run-interrupted.mcap``). They
are read oldest first, and an episode or iteration that a later log of the same directory has
again counts once, as the later log has it. Large sets of logs are read by several processes
at once (``jobs``); the frames are the same, in the same order, whatever their number.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import pandas as pd
from omegaconf import ListConfig, OmegaConf

from inhand_exp.record.reader import Log, LogError, read_log
from inhand_exp.runinfo import CONF_DIR, merged, task_differences

TOPICS = ("/run/config", "/train/iteration", "/eval/episode")  # what the frames are made of
LABELS = ("learner", "variant", "object", "perturb", "noise", "seed")
# overrides that do not change what a policy is (what a run does, where it writes, how long)
NOT_RECIPE = {"seed", "mode", "checkpoint", "goals", "resume", "learner", "object", "perturb",
              "noise", "train.frames", "train.workers", "train.backend", "train.num_envs",
              "learner.cache_dir"}
NOT_RECIPE_PREFIXES = ("hydra", "+hydra", "log.", "eval.")
EVALUATING = ("eval", "demo", "goals")  # modes whose ``goals`` is a test set, not training's
PARALLEL_BYTES = 32 << 20  # logs smaller than this in all are read in this process


def variant(overrides: Iterable[str]) -> str:
    """The recipe of a run, from its overrides: every override that changes the policy (the
    reward, the observation, the training goals...), sorted; "default" when there is none.
    A ``+recipe=`` or ``+profile=`` choice counts as the values its file sets, so a sweep's
    ``+recipe=ppo`` and the same values given one by one are one recipe; a later override of
    a key replaces the earlier value. A training that names no ``goals.train_groups`` trains
    on its own ``goals`` group, so that group is part of its recipe."""
    given = merged([], _expanded(overrides))
    values = dict(o.lstrip("+~").split("=", 1) for o in given if "=" in o)
    if ("goals.train_groups" not in values and "goals" in values
            and values.get("mode") not in EVALUATING):
        given.append(f"goals.train_groups=[{values['goals']}]")
    keep = []
    for o in given:
        key = o.split("=", 1)[0].lstrip("+~")
        if key in NOT_RECIPE or key.startswith(NOT_RECIPE_PREFIXES):
            continue
        keep.append(o)
    return " ".join(sorted(keep)) or "default"


GLOBAL_GROUPS = ("recipe", "profile")  # conf/ groups whose options set keys across the config


def _expanded(overrides: Iterable[str]) -> list[str]:
    """``overrides`` with each ``+recipe=X`` / ``+profile=X`` replaced by the ``key=value``
    overrides its file in ``conf/`` sets (its ``defaults`` choices and ``hydra`` keys left
    out); an option without a file stays as it is."""
    out: list[str] = []
    for o in overrides:
        key, _, value = o.partition("=")
        group = key.lstrip("+~")
        path = CONF_DIR / group / f"{value}.yaml"
        if group not in GLOBAL_GROUPS or not path.is_file():
            out.append(o)
            continue
        settings = OmegaConf.to_container(OmegaConf.load(path))
        out += _as_overrides({k: v for k, v in settings.items()
                              if k not in ("defaults", "hydra")})
    return out


def _as_overrides(tree: dict, prefix: str = "") -> list[str]:
    """``{"a": {"b": [1, 2]}}`` -> ``["a.b=[1,2]"]``, as they are written on a command line."""
    out = []
    for k, v in tree.items():
        if isinstance(v, dict):
            out += _as_overrides(v, f"{prefix}{k}.")
        elif isinstance(v, list):
            out.append(f"{prefix}{k}=[{','.join(map(str, v))}]")
        else:
            out.append(f"{prefix}{k}={v}")
    return out


def _policy_overrides(cfg: dict) -> list[str]:
    """The overrides of the training that made the run's policy: as the run recorded them from
    its checkpoint; for a log written before that record, the ``.hydra`` record beside the
    checkpoint or the checkpoint's own record, when there is one; else the run's own."""
    if "policy_overrides" in cfg:
        return list(cfg["policy_overrides"])
    ckpt = cfg.get("config", {}).get("checkpoint")
    if ckpt:
        saved = Path(ckpt).parent / ".hydra" / "overrides.yaml"
        if saved.is_file():
            loaded = OmegaConf.load(saved)
            if isinstance(loaded, ListConfig):
                return [str(o) for o in loaded]
        recorded = _checkpoint_overrides(Path(ckpt))
        if recorded is not None:
            return recorded
    return list(cfg.get("overrides", []))


@cache
def _checkpoint_overrides(path: Path) -> list[str] | None:
    """The training overrides a checkpoint file records (None: no such file, or none)."""
    if not path.is_file():
        return None
    import torch  # only for logs older than their ``policy_overrides``

    from inhand_exp.learn.checkpoint import trained_with

    try:
        state = torch.load(path, weights_only=True)
    except Exception:  # noqa: BLE001 - not a checkpoint: the run's own overrides serve
        return None
    return trained_with(state) if isinstance(state, dict) else None


@dataclass
class Frames:
    runs: pd.DataFrame
    iterations: pd.DataFrame
    episodes: pd.DataFrame
    skipped: list[tuple[str, str]] = field(default_factory=list)


def find_logs(paths: Iterable[str | Path]) -> list[Path]:
    """Every ``.mcap`` file given, or below a given directory, in a stable order."""
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            out += sorted(p.rglob("*.mcap"))
        elif p.is_file():
            out.append(p)
        else:
            raise FileNotFoundError(f"{p}: no such file or directory")
    return out


def _run_variant(cfg: dict) -> str:
    """The recipe of the run's policy (``variant``), and for a run whose task settings differ
    from its policy's training (a filter option given at evaluation), those settings as the
    run used them (``... | evaluated with task.no_undo=true``): an evaluation with another
    filter is another row of the tables, not more episodes of the same."""
    policy = _policy_overrides(cfg)
    recipe = variant(policy)
    config = cfg.get("config")
    if not isinstance(config, dict):
        return recipe
    unlike = task_differences(OmegaConf.create(config), policy)
    if not unlike:
        return recipe
    return recipe + " | evaluated with " + " ".join(
        sorted(f"{key}={now}" for key, _, now in unlike))


def _run_row(path: Path, cfg: dict, truncated: bool, corrupt: int) -> dict:
    c = cfg.get("config", {})
    return {"log": str(path), "run_dir": str(path.parent),
            "learner": c.get("learner", {}).get("name"), "object": c.get("object", {}).get("name"),
            "perturb": c.get("perturb", {}).get("name"), "noise": c.get("noise", {}).get("name"),
            "seed": cfg.get("seed"), "mode": cfg.get("mode"),
            "variant": _run_variant(cfg),
            "goals": c.get("goals", {}).get("name"),
            "train_frames": c.get("train", {}).get("frames"),
            "checkpoint": c.get("checkpoint"), "truncated": truncated,
            "corrupt_chunks": corrupt}


def _read(path: Path) -> Log | str:
    """The frames' topics of the log at ``path``, or why it is not a run log."""
    try:
        return read_log(path, topics=TOPICS)
    except (LogError, OSError) as err:
        return str(err)


def _read_all(logs: list[Path], jobs: int | None) -> Iterable[Log | str]:
    """``_read`` of each of ``logs``, in order: by up to ``jobs`` processes (default: one per
    core) when they are large enough to pay for starting them."""
    jobs = min(len(logs), jobs or os.cpu_count() or 1)
    if jobs < 2 or sum(p.stat().st_size for p in logs) < PARALLEL_BYTES:
        yield from map(_read, logs)
        return
    with ProcessPoolExecutor(jobs) as pool:
        yield from pool.map(_read, logs)


def load(paths: Iterable[str | Path], warn: Callable[[str], None] = print,
         jobs: int | None = None) -> Frames:
    """The frames of every run log below ``paths``, read by up to ``jobs`` processes."""
    runs, iterations, episodes, skipped = [], [], [], []
    logs = sorted(find_logs(paths), key=lambda p: (str(p.parent), p.stat().st_mtime, p.name))
    for path, log in zip(logs, _read_all(logs, jobs), strict=True):
        if isinstance(log, str):
            skipped.append((str(path), log))
            warn(f"inhand-analyze: skipping {path}: not a run log ({log})")
            continue
        configs = log.topic("/run/config")
        if not configs:
            why = "no /run/config message"
            skipped.append((str(path), why))
            warn(f"inhand-analyze: skipping {path}: {why}")
            continue
        run = _run_row(path, configs[0], log.truncated, log.corrupt_chunks)
        if log.truncated or log.corrupt_chunks:
            warn(f"inhand-analyze: {path}: read "
                 f"{'a truncated log' if log.truncated else 'a damaged log'}"
                 f" ({log.corrupt_chunks} damaged chunks left out)")
        runs.append(run)
        ids = {k: run[k] for k in ("log", "run_dir", *LABELS)}
        for m in log.topic("/train/iteration"):
            flat = {k: v for k, v in m.items() if k != "losses"}
            iterations.append({**ids, **flat, **m.get("losses", {})})
        for m in log.topic("/eval/episode"):
            episodes.append({**m, "log": run["log"], "run_dir": run["run_dir"],
                             "variant": run["variant"]})
    return Frames(pd.DataFrame(runs), _once(pd.DataFrame(iterations), ["iteration"], warn),
                  _once(pd.DataFrame(episodes), ["group", "episode"], warn), skipped)


def _once(frame: pd.DataFrame, keys: list[str], warn: Callable[[str], None]) -> pd.DataFrame:
    """Rows of one run directory that a later log has again (a job run again after an
    interruption), counted once: as the later log has them."""
    if frame.empty or not set(keys) <= set(frame.columns):
        return frame
    repeated = frame.duplicated(["run_dir", *keys], keep="last")
    for run_dir, n in frame[repeated].groupby("run_dir").size().items():
        warn(f"inhand-analyze: {run_dir}: {n} rows of an earlier, interrupted attempt left out "
             f"(a later log of the directory has them again)")
    return frame[~repeated].reset_index(drop=True)
