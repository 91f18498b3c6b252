"""Demonstrations: recorded, read back (successful episodes only), refused when they do not fit,
and cloned by PPO into a policy that acts like the demonstrator."""

from __future__ import annotations

import pytest
import torch
from torchrl.envs.utils import ExplorationType

from inhand_exp.config import PPOConfig
from inhand_exp.envs.toy import ToyLineEnv
from inhand_exp.errors import DemonstrationsError
from inhand_exp.learn.demonstrations import DemoRecorder, clone, load_demonstrations
from inhand_exp.learn.ppo import PPO

SMALL = PPOConfig(frames_per_batch=256, minibatch_size=64, epochs=2, hidden=[64, 64], lr=1e-3)


def expert(td):
    """The toy's best policy: step towards the goal."""
    obs = td["observation"]
    return td.set("action", torch.where(obs[..., 15] > obs[..., 12], 0, 1))


def astray(td):
    """Steps away from the goal: never succeeds (the walls keep it on the line)."""
    obs = td["observation"]
    return td.set("action", torch.where(obs[..., 15] > obs[..., 12], 1, 0))


def record(path, episodes: int, seed: int = 0, stray_every: int = 0):
    """Play ``episodes`` of the toy with the expert (every ``stray_every``-th astray), record
    them, save; the number of steps of the successful episodes."""
    env, rec, kept = ToyLineEnv(seed=seed), DemoRecorder(), 0
    for ep in range(episodes):
        policy = astray if stray_every and ep % stray_every == 0 else expert
        td = env.rollout(env.max_steps, policy=policy, break_when_any_done=True)
        for row in td:
            rec.step(ep, row)
        success = bool(td["next", "success"][-1])
        rec.end({"episode": ep, "success": success, "group": "toy"})
        kept += len(td) if success else 0
    rec.save(path, {"learner": "expert"})
    return kept


def test_only_the_successful_episodes_steps_are_read_back(tmp_path):
    path = tmp_path / "demonstrations.pt"
    kept = record(path, 12, stray_every=3)
    data = load_demonstrations([path], 18, 14)
    assert len(data) == kept > 0
    # every step kept is the expert's, and its own mask allows it
    assert torch.equal(data["action"], expert(data.clone())["action"])
    assert data["action_mask"].gather(-1, data["action"][:, None]).all()
    both = load_demonstrations([path, path], 18, 14)
    assert len(both) == 2 * kept


def test_demonstrations_that_do_not_fit_are_refused_naming_the_file(tmp_path):
    path = tmp_path / "demonstrations.pt"
    record(path, 4)
    with pytest.raises(DemonstrationsError, match=rf"{path}.*18 observations and 14 actions; "
                                                  r"this configuration has 20 and 14"):
        load_demonstrations([path], 20, 14)
    failed = tmp_path / "failed.pt"
    record(failed, 3, stray_every=1)
    with pytest.raises(DemonstrationsError, match="hold no step of a successful episode"):
        load_demonstrations([failed], 18, 14)
    text = tmp_path / "text.pt"
    text.write_text("not demonstrations\n")
    with pytest.raises(DemonstrationsError, match=f"{text} is not a file written by inhand-exp"):
        load_demonstrations([text], 18, 14)
    plain = tmp_path / "plain.pt"
    torch.save({"observation": torch.zeros(2, 18)}, plain)
    with pytest.raises(DemonstrationsError, match="expected the format"):
        load_demonstrations([plain], 18, 14)
    with pytest.raises(FileNotFoundError, match="missing.pt not found"):
        load_demonstrations([tmp_path / "missing.pt"], 18, 14)


def test_cloning_makes_the_untrained_actor_act_like_the_demonstrator(tmp_path, toy_success):
    path = tmp_path / "demonstrations.pt"
    record(path, 60, stray_every=4)
    torch.manual_seed(0)
    data = load_demonstrations([path], 18, 14)
    ppo = PPO(18, 14, SMALL, demos=data)
    greedy = dict(episodes=40, seed=99, mode=ExplorationType.DETERMINISTIC)
    before = toy_success(ppo.actor, **greedy)
    loss = clone(ppo.actor, data, 40, 64, ppo.optim, 1.0)
    after = toy_success(ppo.actor, **greedy)
    assert after >= 0.95 and after > before + 0.2, (before, after, loss)


def test_the_cloning_term_fades_out_over_bc_frames(tmp_path):
    path = tmp_path / "demonstrations.pt"
    record(path, 8)
    params = PPOConfig(**{**SMALL.__dict__, "bc_epochs": 1, "bc_coef": 0.5, "bc_frames": 512})
    torch.manual_seed(0)
    ppo = PPO(18, 14, params, demos=load_demonstrations([path], 18, 14))
    assert ppo.bc_weight() == 0.5
    seen = []
    ppo.train(ToyLineEnv(seed=0), 256 * 3, progress=lambda i, m: seen.append(m))
    # the clone before the first batch, the term at 0.5 and then 0.25, gone at 512 frames
    assert "loss_bc_clone" in seen[0] and all("loss_bc_clone" not in m for m in seen[1:])
    assert [m.get("bc_weight") for m in seen] == [0.5, 0.25, None]
    assert ppo.bc_weight() == 0.0
    assert PPO(18, 14, params).bc_weight() == 0.0  # no demonstrations, no term
