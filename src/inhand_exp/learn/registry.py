"""The learner seam: what ``experiment`` asks of a learner, and the registry of learners by name.

A learner names the environment it acts in (the mid level for PPO and the graph search, joint
torques for DDPG), trains for a number of frames reporting through a callback, acts through a
TorchRL policy module, and saves and loads its state. ``experiment`` only ever calls
``make_learner(cfg)`` and the protocol below, so a new learner is one module and one line here.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from pathlib import Path
from typing import Protocol

from torchrl.envs import EnvBase

from inhand_exp.config import ConfigError

# iteration, metrics: "frames", "collect_s", "learn_s", "mean_reward", "success_rate",
# "drop_rate", and the learner's losses under keys "loss_*"
Progress = Callable[[int, dict[str, float]], None]


class Learner(Protocol):
    """What a run does with a learner."""

    iteration: int  # optimisation iterations done (over every resumed leg)
    frames: int  # environment frames learned from
    per_action_log: bool  # its evaluation logs each action (/episode/action): the mid level
    stochastic: bool  # its policy draws its actions under eval.sample (else it has one answer)
    env_class: type[EnvBase]  # what it acts in, batched by ``envs.batched.batched_env``
    # the overrides of the training that made its policy, saved in and loaded from its
    # checkpoint (None: a checkpoint written before they were recorded, or no training yet)
    trained_with: list[str] | None

    def train(self, env: EnvBase, frames: int, progress: Progress | None = None,
              checkpoint: Path | None = None, checkpoint_every: int = 10) -> None:
        """Learn from ``frames`` more frames of ``env``, saving to ``checkpoint`` on the way."""

    @property
    def policy(self):
        """A TensorDict module writing ``action`` from the environment's observation."""

    def save(self, path: Path) -> None: ...

    def load(self, path: Path) -> None:
        """Restore a state ``save`` wrote; a missing or foreign file is a clean error."""


# learner.name -> "module:factory"; factory(cfg) -> Learner
LEARNERS = {
    "ppo": "inhand_exp.learn.ppo:from_config",
    "ddpg": "inhand_exp.learn.ddpg:from_config",
    "search": "inhand_exp.learn.search:from_config",
}


def make_learner(cfg) -> Learner:
    """The learner ``cfg.learner.name`` names, built from the config."""
    name = cfg.learner.name
    if name not in LEARNERS:
        raise ConfigError(f"learner={name} is not built yet; known learners: "
                          f"{', '.join(sorted(LEARNERS))}")
    module, factory = LEARNERS[name].split(":")
    return getattr(importlib.import_module(module), factory)(cfg)
