"""Shared helpers of the learner tests."""

from __future__ import annotations

from collections.abc import Callable

import pytest
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from inhand_exp.envs.toy import ToyLineEnv


def _toy_success(policy, episodes: int = 60, seed: int = 123,
                 mode: ExplorationType = ExplorationType.RANDOM) -> float:
    """The share of ``episodes`` toy-line episodes ``policy`` solves, acting under ``mode``."""
    env, wins = ToyLineEnv(seed=seed), 0
    for _ in range(episodes):
        with set_exploration_type(mode), torch.no_grad():
            td = env.rollout(env.max_steps, policy=policy, break_when_any_done=True)
        wins += bool(td["next", "success"][-1])
    return wins / episodes


@pytest.fixture
def toy_success() -> Callable[..., float]:
    """toy_success(policy, episodes=60, seed=123, mode=ExplorationType.RANDOM) -> success rate
    on ``ToyLineEnv``."""
    return _toy_success
