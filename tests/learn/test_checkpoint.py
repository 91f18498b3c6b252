"""Hostile checkpoints: random bytes, truncations and foreign pickles are CheckpointErrors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from inhand_exp.config import PPOConfig
from inhand_exp.envs.specs import OBS_DIM
from inhand_exp.learn.checkpoint import CheckpointError
from inhand_exp.learn.ppo import PPO


def small() -> PPO:
    return PPO(OBS_DIM, 14, PPOConfig(hidden=[16]))


def test_random_truncated_and_foreign_checkpoints_are_refused(tmp_path):
    good = tmp_path / "good.pt"
    small().save(good)
    data = good.read_bytes()
    rng = np.random.default_rng(11)
    cases = [rng.bytes(int(n)) for n in rng.integers(0, 5000, 10)]
    cases += [data[:int(n)] for n in rng.integers(0, len(data), 10)]  # truncated
    flipped = bytearray(data)
    for i in rng.integers(0, len(data), 20):
        flipped[i] ^= 0xFF
    cases.append(bytes(flipped))
    for k, payload in enumerate(cases):
        path = tmp_path / f"c{k}.pt"
        path.write_bytes(payload)
        try:
            small().load(path)
        except CheckpointError as err:
            assert str(path) in str(err)
    for k, obj in enumerate([[1, 2], {"iteration": 1}, {"frames": 0, "iteration": 0},
                             {"learner": "ddpg", "iteration": 0, "frames": 0},
                             "text", torch.zeros(3)]):
        path = tmp_path / f"o{k}.pt"
        torch.save(obj, path)
        with pytest.raises(CheckpointError):
            small().load(path)


def test_networks_of_another_size_are_refused(tmp_path):
    path = tmp_path / "wide.pt"
    PPO(OBS_DIM, 14, PPOConfig(hidden=[32, 32])).save(path)
    with pytest.raises(CheckpointError, match="does not fit this configuration"):
        small().load(path)
