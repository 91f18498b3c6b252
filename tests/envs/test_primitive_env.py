"""The mid-level environment: specs, mask = filter, determinism, rewards and termination."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torchrl.envs.utils import check_env_specs

from inhand_exp.control.execute import Observation
from inhand_exp.control.grasp import Contacts, Face, Posture
from inhand_exp.control.hand import HandModel
from inhand_exp.envs.primitive_env import OUTCOMES, PrimitiveEnv
from inhand_exp.task.actions import make_primitive
from inhand_exp.task.goals import GoalPair

L, R = Face.LEFT, Face.RIGHT
BEND = Contacts(Posture((L, L, R)), (-0.21, -0.09, -0.15))
X0 = np.array([0.0, 0.34, 0.0])
XF = np.array([0.0, 0.40, 0.0])


def one_pair(dx: float) -> list[GoalPair]:
    return [GoalPair("easy", X0.copy(), X0 + np.array([dx, 0.0, 0.0]), BEND)]


@pytest.mark.parametrize("overrides", [[], ["object=cube"]], ids=["pole", "cube"])
def test_env_specs(compose_cfg, overrides):
    env = PrimitiveEnv(compose_cfg("task.max_actions=3", "goals=easy", *overrides), seed=0)
    check_env_specs(env)
    assert env.action_spec.n == len(env.actions)


def test_mask_is_the_set_of_actions_the_primitives_accept(compose_cfg):
    env = PrimitiveEnv(compose_cfg(), goals=one_pair(0.05), seed=0)
    td = env.reset()
    pose, twist = env.world.object_state()
    q, qd = env.world.joint_state()
    obs = Observation(q, qd, pose, twist, 0.0)
    expected = [make_primitive(a, env.model, BEND, env.prim).start(obs) is None
                for a in env.actions]
    assert td["action_mask"].tolist() == expected
    assert any(expected) and not all(expected)


def test_one_repose_to_the_goal_succeeds_with_the_goal_reward(compose_cfg):
    env = PrimitiveEnv(compose_cfg(), goals=one_pair(0.012), seed=0)
    env.reset()
    plus_x = next(a.index for a in env.actions if a.name == "repose +x")
    td = env.step(env.reset().set("action", torch.tensor(plus_x)))["next"]
    assert td["success"].item() and td["terminated"].item() and td["done"].item()
    assert td["reward"].item() == pytest.approx(5.0)
    assert abs(env.world.object_pose()[0] - 0.01) < 2e-3  # simulated, not commanded


def test_penalty_mode_rejected_action_costs_and_does_not_move(compose_cfg):
    env = PrimitiveEnv(compose_cfg("task.filter=penalty"), goals=one_pair(0.05), seed=0)
    td = env.reset()
    assert td["action_mask"].all()  # penalty mode lets the policy pick anything
    flip = next(a.index for a in env.actions if a.kind == "flip")
    assert not env.mask[flip]  # the bend grasp cannot flip
    before = env.world.object_state()[0].copy(), env.world.joint_q().copy()
    out = env.step(td.set("action", torch.tensor(flip)))["next"]
    assert out["reward"].item() == pytest.approx(-0.01)
    np.testing.assert_array_equal(env.world.object_state()[0], before[0])
    np.testing.assert_array_equal(env.world.joint_q(), before[1])
    assert not out["done"].item()


def test_time_limit_truncates(compose_cfg):
    env = PrimitiveEnv(compose_cfg("task.max_actions=2"), goals=one_pair(0.3), seed=0)
    td = env.rollout(5, break_when_any_done=True)
    assert td.shape == (2,)
    assert td["next", "truncated"][-1].item() and not td["next", "terminated"][-1].item()


def test_same_seed_same_rollout(compose_cfg):
    def run() -> torch.Tensor:
        env = PrimitiveEnv(compose_cfg("task.max_actions=3", "goals=medium"), seed=7)

        def first_allowed(td):  # a fixed policy: the env's own randomness is under test
            return td.set("action", td["action_mask"].float().argmax(-1))

        td = env.rollout(3, policy=first_allowed, break_when_any_done=False)
        return torch.cat([td["observation"], td["next", "observation"],
                          td["action"][:, None].float()], dim=-1)

    assert torch.equal(run(), run())


@pytest.mark.parametrize(("angle", "seen_before", "needed", "paid"), [
    (0.6, False, None, 1.0),   # the flipped finger pushes the pole towards the goal angle
    (-0.6, False, None, 0.0),  # ... away from it
    (0.6, True, None, 0.0),    # useful, but the posture was already reached in this episode
    (0.6, False, True, 1.0),   # task.reward_flip_needed: the pair needs a flip
    (0.6, False, False, 0.0),  # ... it does not
])
def test_flip_reward_is_paid_for_useful_flips_to_new_postures(compose_cfg, angle, seen_before,
                                                              needed, paid):
    start = Contacts(Posture((L, R, R)), (-0.21, -0.205, -0.15))
    pair = GoalPair("hard", XF.copy(), XF + np.array([0.0, 0.0, angle]), start, bool(needed))
    overrides = () if needed is None else ("task.reward_flip_needed=true",)
    env = PrimitiveEnv(compose_cfg(*overrides), goals=[pair], seed=0)
    td = env.reset()
    if seen_before:
        env.postures.add(Posture((L, R, L)))
    flip = next(a.index for a in env.actions if a.name == "flip right")
    assert td["action_mask"][flip]
    out = env.step(td.set("action", torch.tensor(flip)))["next"]
    assert str(env.contacts.posture) == "left/right/left"
    assert OUTCOMES[int(out["outcome"])] == "done"
    assert out["reward"].item() == pytest.approx(paid)


def test_no_undo_flip_refuses_the_same_flip_right_after_it(compose_cfg):
    start = Contacts(Posture((L, R, R)), (-0.21, -0.205, -0.15))
    pair = GoalPair("hard", XF.copy(), XF + np.array([0.0, 0.0, 0.6]), start, True)
    allowed = []
    for overrides in ([], ["task.no_undo_flip=true"]):
        env = PrimitiveEnv(compose_cfg(*overrides), goals=[pair], seed=0)
        td = env.reset()
        flip = next(a.index for a in env.actions if a.name == "flip right")
        td = env.step(td.set("action", torch.tensor(flip)))["next"]
        assert OUTCOMES[int(td["outcome"])] == "done"
        assert str(env.contacts.posture) == "left/right/left"
        allowed.append({a.name for a in env.actions if td["action_mask"][a.index]})
    assert "flip right" in allowed[0]  # the filter alone would carry finger 2 straight back
    assert allowed[1] == allowed[0] - {"flip right"}


def test_training_episodes_mix_the_listed_groups(compose_cfg):
    mixed = PrimitiveEnv(compose_cfg("goals=easy", "goals.train_groups=[medium,hard]"), seed=0)
    plain = PrimitiveEnv(compose_cfg("goals=easy"), seed=0)
    groups, own = set(), set()
    for _ in range(12):
        mixed.reset()
        plain.reset()
        groups.add(mixed.task.pair.group)
        own.add(plain.task.pair.group)
    assert groups == {"medium", "hard"} and own == {"easy"}


def test_once_idles_after_the_last_goal(compose_cfg):
    env = PrimitiveEnv(compose_cfg("task.max_actions=2"), goals=one_pair(0.05), seed=0,
                       once=True)
    td = env.reset()
    for _ in range(2):
        td["action"] = torch.tensor(0)  # repose +x: allowed here
        td = env.step(td)["next"]
    assert bool(td["done"]) and env.world.time_s > 0
    clock = env.world.time_s
    td = env.reset()
    assert env.idle and not bool(td["done"])
    td["action"] = torch.tensor(0)
    out = env.step(td)["next"]
    assert bool(out["done"]) and float(out["reward"]) == 0.0 and not bool(out["terminated"])
    assert env.world.time_s == clock  # nothing simulated


def test_contact_bookkeeping_reads_the_observed_pose_under_noise(compose_cfg, monkeypatch):
    """With noise=paper the controllers' contacts come from the noisy pose they observe."""
    seen = []
    measured = HandModel.measured

    def spy(model, contacts, pose, q):
        seen.append(np.array(pose, dtype=float))
        return measured(model, contacts, pose, q)

    monkeypatch.setattr(HandModel, "measured", spy)
    env = PrimitiveEnv(compose_cfg("noise=paper"), goals=one_pair(0.05), seed=3)
    td = env.reset()
    for _ in range(3):
        seen.clear()
        assert env.offset.any()  # noise was drawn
        observed = env.pose + env.offset  # what the controllers and the policy saw
        np.testing.assert_allclose(td["observation"][12:15].numpy(), observed, atol=1e-6)
        td = env.step(td.set("action", td["action_mask"].float().argmax(-1)))["next"]
        true_now = env.world.object_pose()
        book = [p for p in seen if np.allclose(p, env.pose + env.offset)]
        assert book, "the contacts were not measured with the observed pose"
        assert not any(np.allclose(p, true_now) for p in seen)


def test_limp_finger_in_the_env_is_a_drop_when_the_pole_falls(compose_cfg):
    """A finger that goes limp during an action: a fall of more than 2 cm is recorded as a
    drop, whatever the primitive itself reported."""
    falls = []
    for finger in range(3):
        env = PrimitiveEnv(compose_cfg(), goals=one_pair(0.05), seed=0)
        td = env.reset()
        step = env.world.step

        def limp(tau, finger=finger, step=step):
            tau = np.array(tau, dtype=float)
            tau[2 * finger:2 * finger + 2] = 0.0
            step(tau)

        env.world.step = limp
        z0 = env.world.object_pose()[1]
        plus_x = next(a.index for a in env.actions if a.name == "repose +x")
        out = env.step(td.set("action", torch.tensor(plus_x)))["next"]
        fell = z0 - env.world.object_pose()[1]
        falls.append(fell)
        if fell > 0.02:
            assert out["dropped"].item() and out["done"].item(), (finger, fell)
    assert max(falls) > 0.02  # some finger's loss lets the pole fall


def test_a_nan_torque_ends_the_episode_as_a_failure_and_the_env_goes_on(compose_cfg,
                                                                        monkeypatch):
    """A controller fault (NaN torques half-way through a repose) never reaches the simulator:
    the step ends as ``unstable`` (a failure, counted as a drop) and the next episode plays."""
    from inhand_exp.control.repose import Repose

    good = Repose.torques
    calls = {"n": 0}

    def faulty(self, obs):
        calls["n"] += 1
        tau = good(self, obs)
        return tau if calls["n"] < 20 or tau is None else np.full(6, np.nan)

    monkeypatch.setattr(Repose, "torques", faulty)
    env = PrimitiveEnv(compose_cfg(), goals=one_pair(0.05) * 2, seed=0)
    td = env.reset()
    plus_x = next(a.index for a in env.actions if a.name == "repose +x")
    out = env.step(td.set("action", torch.tensor(plus_x)))["next"]
    assert OUTCOMES[int(out["outcome"])] == "unstable"
    assert out["done"].item() and out["dropped"].item() and not out["success"].item()
    assert np.isfinite(env.world.object_pose()).all()
    monkeypatch.setattr(Repose, "torques", good)
    td = env.reset()
    np.testing.assert_allclose(env.world.object_pose(), X0, atol=1e-9)
    out = env.step(td.set("action", torch.tensor(plus_x)))["next"]
    assert OUTCOMES[int(out["outcome"])] == "done"


def test_the_world_refuses_a_nan_torque_and_clips_an_absurd_one(compose_cfg):
    env = PrimitiveEnv(compose_cfg(), goals=one_pair(0.05), seed=0)
    env.reset()
    with pytest.raises(ValueError, match="non-finite joint torque"):
        env.world.step(np.array([0.0, np.nan, 0.0, 0.0, 0.0, 0.0]))
    env.world.step(np.full(6, 1e12))  # clipped to hand.max_torque_nm: a physical command
    pose, twist = env.world.object_state()
    assert np.isfinite(pose).all() and np.isfinite(twist).all()


def test_no_undo_refuses_the_opposite_of_the_last_action_only(compose_cfg):
    names = lambda env, mask: {a.name for a in env.actions if mask[a.index]}  # noqa: E731
    envs = [PrimitiveEnv(compose_cfg(*o), goals=one_pair(0.05), seed=0)
            for o in ([], ["task.no_undo=true"])]
    allowed = []
    for env in envs:
        td = env.reset()
        plus_x = next(a.index for a in env.actions if a.name == "repose +x")
        assert td["action_mask"][plus_x]
        td = env.step(td.set("action", torch.tensor(plus_x)))["next"]
        assert OUTCOMES[td["outcome"].item()] == "done"
        allowed.append(names(env, td["action_mask"]))
    assert "repose -x" in allowed[0]
    assert allowed[1] == allowed[0] - {"repose -x"}
    assert envs[1].reset()["action_mask"].tolist() == envs[0].reset()["action_mask"].tolist()


def test_no_repeat_contact_refuses_the_move_that_just_rested_the_pole_on_the_palm(compose_cfg):
    """A pole 5 cm longer than the controllers' model: `repose -z` from this start rests its
    real lower end on the palm (`link_contact`), the filter on the nominal ends allows it
    again, and with the option it is refused right after, and only then."""
    x0 = np.array([-0.0443, 0.2816, 0.0552])  # the start of a medium test pair
    pair = GoalPair("medium", x0.copy(), np.array([-0.04, 0.226, -0.54]),
                    Contacts(Posture((L, R, R)), (-0.095, -0.04, -0.12)))
    masks = []
    for overrides in ([], ["task.no_repeat_contact=true"]):
        env = PrimitiveEnv(compose_cfg("perturb=longer", *overrides), goals=[pair], seed=0)
        td = env.reset()
        down = next(a.index for a in env.actions if a.name == "repose -z")
        assert td["action_mask"][down]
        td = env.step(td.set("action", torch.tensor(down)))["next"]
        assert OUTCOMES[int(td["outcome"])] == "link_contact"
        assert "palm" in env.world.hand_contacts()
        masks.append(td["action_mask"].clone())
    assert masks[0][down] and not masks[1][down]
    masks[1][down] = True
    assert torch.equal(masks[0], masks[1])  # nothing else refused


def test_touch_finds_length_plans_on_the_pole_as_long_as_the_palm_found_it(compose_cfg):
    """The pole 10 % longer than the model: `repose -z` rests its real end on the palm. With
    the option the model takes the length the palm's touch shows (0.55 m, not 0.50), the move
    down is refused from then on, and a new episode starts from the nominal model again."""
    x0 = np.array([-0.0443, 0.2816, 0.0552])  # the start of a medium test pair
    pair = GoalPair("medium", x0.copy(), np.array([-0.04, 0.226, -0.54]),
                    Contacts(Posture((L, R, R)), (-0.095, -0.04, -0.12)))
    lengths, refused = [], []
    for overrides in ([], ["task.touch_finds_length=true"]):
        env = PrimitiveEnv(compose_cfg("perturb=longer", *overrides), goals=[pair, pair],
                           seed=0)
        td = env.reset()
        down = next(a.index for a in env.actions if a.name == "repose -z")
        td = env.step(td.set("action", torch.tensor(down)))["next"]
        assert OUTCOMES[int(td["outcome"])] == "link_contact"
        lengths.append(env.model.shape.length_m)
        refused.append(not td["action_mask"][down])
        env.reset()
        assert env.model.shape.length_m == 0.5
    assert lengths[0] == 0.5 and not refused[0]
    assert lengths[1] == pytest.approx(0.55, abs=0.003) and refused[1]
