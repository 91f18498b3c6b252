"""The learner seam: the registry builds learners by name and refuses unknown ones."""

from __future__ import annotations

import pytest
from omegaconf import OmegaConf

from inhand_exp.config import ConfigError
from inhand_exp.learn.ppo import PPO
from inhand_exp.learn.registry import LEARNERS, make_learner


def test_registry_builds_ppo_from_the_config(compose_cfg):
    learner = make_learner(compose_cfg("learner.hidden=[32,32]"))
    assert isinstance(learner, PPO) and learner.params.hidden == [32, 32]
    assert learner.per_action_log and learner.policy is learner.actor


def test_registry_builds_every_learner_it_lists(compose_cfg, tmp_path):
    from inhand_exp.learn.ddpg import DDPG
    from inhand_exp.learn.search import Search

    kinds = {"ppo": PPO, "ddpg": DDPG, "search": Search}
    assert set(LEARNERS) == set(kinds)
    for name, kind in kinds.items():
        extra = [f"learner.cache_dir={tmp_path}"] if name == "search" else []
        assert isinstance(make_learner(compose_cfg(f"learner={name}", *extra)), kind)


def test_registry_refuses_an_unknown_name_listing_the_known_ones():
    with pytest.raises(ConfigError) as err:
        make_learner(OmegaConf.create({"learner": {"name": "sac"}}))
    for name in LEARNERS:
        assert name in str(err.value)


def test_a_learner_says_whether_its_policy_draws_its_actions(compose_cfg):
    """``stochastic`` is what the policy does under sampling: PPO's actions vary over draws on
    one observation, DDPG's actor gives one answer (the evaluation printout says which)."""
    import torch
    from tensordict import TensorDict
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from inhand_exp.envs.specs import OBS_DIM

    torch.manual_seed(0)
    for name in ("ppo", "ddpg"):
        learner = make_learner(compose_cfg(f"learner={name}"))
        td = TensorDict({"observation": torch.randn(64, OBS_DIM)}, [64])
        if name == "ppo":
            td["action_mask"] = torch.ones(64, 14, dtype=torch.bool)
        with set_exploration_type(ExplorationType.RANDOM), torch.no_grad():
            a, b = (learner.policy(td.clone())["action"] for _ in range(2))
        assert learner.stochastic == (not torch.equal(a, b)), name
