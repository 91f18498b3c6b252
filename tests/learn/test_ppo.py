"""PPO learns the toy task, reports progress, and checkpoints resume exactly."""

from __future__ import annotations

import pytest
import torch

from inhand_exp.config import PPOConfig
from inhand_exp.envs.toy import ToyLineEnv
from inhand_exp.learn.ppo import PPO

SMALL = PPOConfig(frames_per_batch=256, minibatch_size=64, epochs=4, hidden=[64, 64], lr=1e-3)


def random_masked(td):
    """Uniform over the allowed actions, for any batch shape."""
    mask = td["action_mask"].float()
    pick = torch.multinomial(mask.reshape(-1, mask.shape[-1]), 1)
    return td.set("action", pick.reshape(td.shape))


def test_ppo_beats_a_random_policy_on_the_toy_task(toy_success):
    torch.manual_seed(0)
    ppo = PPO(18, 14, SMALL)
    seen = []
    ppo.train(ToyLineEnv(seed=0), 256 * 12, progress=lambda i, m: seen.append((i, m["frames"])))
    assert seen == [(i, 256 * i) for i in range(1, 13)]
    torch.manual_seed(1)
    random_rate = toy_success(random_masked)
    torch.manual_seed(1)
    trained_rate = toy_success(ppo.actor)
    assert trained_rate >= 0.9 and trained_rate > random_rate + 0.2, (trained_rate, random_rate)


def test_checkpoint_round_trip_resumes(tmp_path):
    torch.manual_seed(0)
    ppo = PPO(18, 14, SMALL)
    path = tmp_path / "policy.pt"
    ppo.train(ToyLineEnv(seed=0), 256 * 2, checkpoint=path)
    assert path.is_file() and not path.with_suffix(".pt.tmp").exists()
    back = PPO(18, 14, SMALL)
    back.load(path)
    assert (back.iteration, back.frames) == (2, 512)
    for a, b in zip(ppo.loss.parameters(), back.loss.parameters(), strict=True):
        assert torch.equal(a, b)
    assert back.optim.state_dict()["state"].keys() == ppo.optim.state_dict()["state"].keys()
    back.train(ToyLineEnv(seed=1), 256)
    assert (back.iteration, back.frames) == (3, 768)


def test_checkpoint_for_another_observation_size_is_refused(tmp_path):
    path = tmp_path / "policy.pt"
    PPO(18, 14, SMALL).save(path)
    with pytest.raises(ValueError, match="18 observations and 14 actions; this configuration "
                                         "has 19 and 14"):
        PPO(19, 14, SMALL).load(path)
    with pytest.raises(FileNotFoundError, match="not found"):
        PPO(18, 14, SMALL).load(tmp_path / "missing.pt")


def test_ppo_runs_on_the_primitive_environment(compose_cfg):
    from inhand_exp.envs.primitive_env import PrimitiveEnv
    from inhand_exp.envs.specs import OBS_DIM

    env = PrimitiveEnv(compose_cfg("goals=easy", "task.max_actions=4"), seed=0)
    ppo = PPO(OBS_DIM, len(env.actions), PPOConfig(frames_per_batch=8, minibatch_size=4,
                                                   epochs=1, hidden=(32, 32)))
    seen = []
    ppo.train(env, 16, progress=lambda i, m: seen.append(m))
    assert [m["frames"] for m in seen] == [8, 16]
    assert all(0.0 <= m["success_rate"] <= 1.0 and 0.0 <= m["drop_rate"] <= 1.0 for m in seen)
    # the iteration's wall time split into collecting (the physics) and learning
    assert all(m["collect_s"] > 0.0 and m["learn_s"] > 0.0 for m in seen)


@pytest.mark.slow
def test_tiny_ppo_run_beats_random_on_easy_goals(compose_cfg):
    """A couple of CPU minutes of PPO on easy goals (with progress shaping) beats random."""
    from inhand_exp.control.hand import HandModel
    from inhand_exp.envs.batched import batched_env
    from inhand_exp.learn.evaluate import evaluate
    from inhand_exp.task.goals import goal_set

    cfg = compose_cfg("goals=easy", "task.max_actions=8", "task.reward_progress=0.1",
                      "train.num_envs=8", "train.workers=2")
    params = PPOConfig(frames_per_batch=256, minibatch_size=64, epochs=8, lr=1e-3)
    torch.manual_seed(0)
    ppo = PPO(18, 14, params)
    env = batched_env(cfg, seed=0)
    ppo.train(env, 256 * 6)
    model = HandModel.from_config(cfg.hand, cfg.object, cfg.sim.gravity_mps2)
    goals = goal_set(model, "easy", 48, cfg.goals.seed)
    rates = []
    for policy in (random_masked, ppo.actor):
        test = batched_env(cfg, seed=1, goals=goals)
        rates.append(evaluate(test, policy, goals)["success_rate"])
        test.close()
    assert rates[1] > rates[0] + 0.15, rates


def test_checkpoint_with_other_network_inputs_is_refused(tmp_path):
    from inhand_exp.learn.features import HandGeometry

    hand = HandGeometry((-0.12, 0.0, 0.12), 0.0, 0.16, 0.16)
    path = tmp_path / "policy.pt"
    PPO(18, 14, SMALL, hand).save(path)
    with pytest.raises(ValueError, match="grasp_features=True; this configuration has "
                                         "learner.grasp_features=False"):
        PPO(18, 14, SMALL).load(path)
    back = PPO(18, 14, SMALL, hand)
    back.load(path)  # the same inputs load
