"""What a run records about itself: resolved config, package versions, git state, start time."""

from __future__ import annotations

import dataclasses
import datetime as dt
import enum
import importlib.metadata
import math
import platform
import subprocess
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import yaml
from omegaconf import DictConfig, ListConfig, OmegaConf

from inhand_exp.config import TaskConfig

CONF_DIR = Path(__file__).resolve().parents[2] / "conf"  # the app's config tree
PACKAGES = ("inhand-exp", "torch", "torchrl", "tensordict", "pybullet", "hydra-core",
            "omegaconf", "mcap", "numpy", "scipy", "pandas")


def package_versions() -> dict[str, str]:
    """Installed versions of the packages that decide a run's results, plus Python's."""
    versions = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def git_state(path: Path) -> dict[str, Any] | None:
    """Commit and dirty flag of the checkout holding ``path``, or None outside git."""
    try:
        def git(*args: str) -> str:
            return subprocess.run(["git", *args], cwd=path, capture_output=True, text=True,
                                  check=True, timeout=10).stdout.strip()
        return {"commit": git("rev-parse", "HEAD"),
                "dirty": bool(git("status", "--porcelain", "--untracked-files=no"))}
    except (OSError, subprocess.SubprocessError):
        return None


def run_config_message(cfg: DictConfig, run_dir: Path, overrides: list[str],
                       policy_overrides: list[str] | None = None) -> dict[str, Any]:
    """The ``/run/config`` message: everything needed to reproduce the run, and the overrides
    of the training that made the policy it runs (``policy_overrides``, when known)."""
    message = {
        "config": OmegaConf.to_container(cfg, resolve=True, enum_to_str=True),
        "versions": package_versions(),
        "seed": int(cfg.seed),
        "mode": str(cfg.mode.value if hasattr(cfg.mode, "value") else cfg.mode),
        "overrides": list(overrides),
        "run_dir": str(run_dir),
        "started_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
    }
    if policy_overrides is not None:
        message["policy_overrides"] = list(policy_overrides)
    git = git_state(Path(__file__).resolve().parent)
    if git is not None:  # omitted outside a checkout: the schema has no null types
        message["git"] = git
    return message


def merged(first: Iterable[str], then: Iterable[str]) -> list[str]:
    """Overrides ``first`` followed by ``then``, one per key: a later value replaces an
    earlier one in its place."""
    out: dict[str, str] = {}
    for o in (*first, *then):
        out[o.split("=", 1)[0].lstrip("+~")] = o
    return list(out.values())


def _plain(value: Any) -> Any:
    """A config value as plain Python (an enum by its value, containers as lists and dicts)."""
    if isinstance(value, enum.Enum):
        return value.value
    if isinstance(value, DictConfig | ListConfig):
        return OmegaConf.to_container(value, resolve=True, enum_to_str=True)
    return value


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, int | float) and isinstance(b, int | float) and not isinstance(a, bool):
        return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12)
    return a == b or str(a) == str(b)


def _compared(key: str) -> bool:
    """Whether a task setting counts in ``unlike_training``: not a reward (it does not change
    what the policy sees or may do) and not where a cache is kept."""
    return key.startswith("task.") and not key.startswith("task.reward_") \
        and key != "task.route_cache_dir"


def unlike_training(cfg: DictConfig, policy_overrides: Iterable[str] | None) -> list[str]:
    """The task settings a policy was trained with (``policy_overrides``, its ``trained_with``)
    that ``cfg`` does not use, each as ``key=trained (here: now)``: those the training set,
    then those it left at their defaults and ``cfg`` sets otherwise. Rewards are left out: they
    do not change what the policy sees or may do. Evaluated otherwise, a policy meets a filter,
    a time limit or an observation it did not learn with. A policy that records no
    ``trained_with`` (None) has nothing to compare."""
    return [f"{key}={trained} (here: {now})"
            for key, trained, now in task_differences(cfg, policy_overrides)]


def task_differences(cfg: DictConfig, policy_overrides: Iterable[str] | None
                     ) -> list[tuple[str, str, Any]]:
    """``unlike_training``'s settings as ``(key, trained, now)``: the value the training
    used and the one ``cfg`` has, each as an override writes it."""
    if policy_overrides is None:
        return []
    unlike, seen = [], set()
    for override in policy_overrides:
        key, sep, text = override.partition("=")
        key = key.lstrip("+~")
        if not sep or not _compared(key):
            continue
        seen.add(key)
        try:
            trained = yaml.safe_load(text)
        except yaml.YAMLError:
            trained = text
        now = _plain(OmegaConf.select(cfg, key, default=None))
        if not _same(trained, now):
            unlike.append((key, text, _shown(now)))
    for field in dataclasses.fields(TaskConfig):
        key = f"task.{field.name}"
        if key in seen or not _compared(key):
            continue
        default = _plain(field.default_factory() if field.default is dataclasses.MISSING
                         else field.default)
        now = _plain(OmegaConf.select(cfg, key, default=None))
        if now is not None and not _same(default, now):
            unlike.append((key, str(_shown(default)), _shown(now)))
    return unlike


def _shown(value: Any) -> Any:
    """A value as an override writes it (booleans in lower case)."""
    return str(value).lower() if isinstance(value, bool) else value
