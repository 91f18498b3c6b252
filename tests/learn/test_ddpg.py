"""DDPG learns the continuous toy task, checkpoints resume, the torque env fits it."""

from __future__ import annotations

import pytest
import torch
from torchrl.envs.utils import ExplorationType, check_env_specs, set_exploration_type

from inhand_exp.config import DDPGConfig
from inhand_exp.envs.specs import OBS_DIM
from inhand_exp.envs.toy import ToyReachEnv
from inhand_exp.learn.checkpoint import CheckpointError
from inhand_exp.learn.ddpg import DDPG

SMALL = DDPGConfig(hidden=[64, 64], warmup_frames=400, frames_per_batch=200,
                   updates_per_batch=100, batch_size=64, actor_lr=1e-3, exploration_std=0.3,
                   buffer_size=20_000, gamma=0.9)


def success_rate(policy, episodes: int = 50, seed: int = 7) -> float:
    env = ToyReachEnv(seed=seed)
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        wins = 0
        for _ in range(episodes):
            td = env.rollout(env.max_steps, policy)
            wins += bool(td["next", "success"].any())
    return wins / episodes


def test_ddpg_learns_the_toy_reach_task():
    torch.manual_seed(0)
    ddpg = DDPG(OBS_DIM, 6, 1.0, SMALL)
    before = success_rate(ddpg.policy)
    seen = []
    ddpg.train(ToyReachEnv(seed=0), 4000, progress=lambda i, m: seen.append(m))
    after = success_rate(ddpg.policy)
    assert after >= 0.9 and after > before + 0.3, (before, after)
    assert seen[-1]["frames"] == 4000 and {"loss_actor", "loss_value"} <= set(seen[-1])


def test_the_observation_is_standardised_by_the_warm_up_before_any_gradient_step():
    torch.manual_seed(0)
    ddpg = DDPG(OBS_DIM, 6, 1.0, SMALL)
    seen = []
    ddpg.train(ToyReachEnv(seed=3), 600, progress=lambda i, m: seen.append(m))
    assert [("loss_value" in m) for m in seen] == [False, True, True]  # warm-up: 2 batches
    warm = ddpg.buffer[:400]["observation"]
    actor, critic = ddpg.norms
    assert actor.fitted and critic.fitted
    torch.testing.assert_close(actor.loc, warm.mean(0))
    torch.testing.assert_close(actor.scale, warm.std(0).clamp_min(1e-2))
    torch.testing.assert_close(critic.loc, actor.loc)
    targets = ddpg.loss.target_actor_network_params.flatten_keys(".")
    loc = next(v for k, v in targets.items() if k.endswith("loc"))
    torch.testing.assert_close(loc, actor.loc)  # the target network standardises the same way


def test_checkpoint_round_trip_and_refusals(tmp_path):
    torch.manual_seed(0)
    a = DDPG(OBS_DIM, 6, 1.0, SMALL)
    a.train(ToyReachEnv(seed=1), 600, checkpoint=tmp_path / "policy.pt")
    b = DDPG(OBS_DIM, 6, 1.0, SMALL)
    b.load(tmp_path / "policy.pt")
    assert (b.iteration, b.frames) == (a.iteration, a.frames) == (3, 600)
    obs = ToyReachEnv(seed=2).reset()
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        torch.testing.assert_close(a.policy(obs.clone())["action"],
                                   b.policy(obs.clone())["action"])
    with pytest.raises(FileNotFoundError):
        b.load(tmp_path / "missing.pt")
    from inhand_exp.config import PPOConfig
    from inhand_exp.learn.ppo import PPO

    with pytest.raises(CheckpointError, match="learner=ddpg"):
        PPO(OBS_DIM, 14, PPOConfig(hidden=[8])).load(tmp_path / "policy.pt")


def test_torque_env_specs_and_a_limp_hand_drops_the_pole(compose_cfg):
    from inhand_exp.envs.torque_env import TorqueEnv

    env = TorqueEnv(compose_cfg("learner=ddpg", "goals=easy", "learner.train_pool=2"), seed=0)
    check_env_specs(env)
    td = env.reset()
    z0 = env.world.object_pose()[1]
    for _ in range(120):  # 2 s of zero torques
        td = env.step(td.set("action", torch.zeros(6)))["next"]
        if td["done"]:
            break
    assert td["dropped"].item() and td["terminated"].item() and not td["success"].item()
    assert env.world.object_pose()[1] < z0  # it fell under gravity
    assert td["sim_time_s"].item() < 1.0
