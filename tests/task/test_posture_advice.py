"""The posture advice: what the fingers' posture can still do for the goal, in the observation."""

from __future__ import annotations

import numpy as np
import pytest

from inhand_exp.config import HandConfig, ObjectConfig
from inhand_exp.control.grasp import Contacts
from inhand_exp.control.hand import HandModel
from inhand_exp.envs.primitive_env import PrimitiveEnv
from inhand_exp.task.goals import goal_set, lone_finger
from inhand_exp.task.posture_advice import PostureAdvice

TOL = (0.01, 0.1)


@pytest.fixture(scope="module")
def model() -> HandModel:
    return HandModel.from_config(HandConfig(), ObjectConfig(), 9.81)


@pytest.fixture(scope="module")
def pairs(model):
    return goal_set(model, "medium", 16, seed=11) + goal_set(model, "hard", 24, seed=11)


def test_at_the_start_the_flags_are_the_goal_sets_own_verdicts(model, pairs):
    advice = PostureAdvice(model, TOL)
    got = np.array([advice(p.contacts, p.xg) for p in pairs])
    want = np.array([[p.needs_flip, p.lone_down] for p in pairs], dtype=float)
    np.testing.assert_array_equal(got, want)
    assert want[:, 0].any() and want[:, 1].any()  # both kinds occur in these sets
    again = np.array([advice(p.contacts, p.xg) for p in reversed(pairs)])[::-1]
    np.testing.assert_array_equal(again, want)  # the kept answers are the goal's own


def test_the_lone_flag_clears_once_the_lone_finger_is_low_enough(model, pairs):
    """A pair whose lone finger must descend: with that finger at the pole's lower end, no
    grasp needs it lower; a few millimetres lower than at the start is not enough."""
    advice = PostureAdvice(model, TOL)
    down = [p for p in pairs if p.lone_down]
    for p in down:
        lone = lone_finger(p.contacts.posture)
        coords = list(p.contacts.coords)
        coords[lone] = -model.shape.half_z
        low = Contacts(p.contacts.posture, tuple(coords))
        assert advice(low, p.xg)[1] == 0.0
        coords[lone] = p.contacts.coords[lone] - 0.002
        assert advice(Contacts(p.contacts.posture, tuple(coords)), p.xg)[1] == 1.0


def test_posture_advice_extends_the_observation_and_other_sizes_are_refused(compose_cfg,
                                                                              tmp_path):
    from inhand_exp.errors import CheckpointError
    from inhand_exp.learn import ppo

    plain, advised = compose_cfg(), compose_cfg("task.posture_advice=true")
    sizes = []
    for cfg in (plain, advised):
        env = PrimitiveEnv(cfg, seed=0)
        try:
            td = env.reset()
            sizes.append(td["observation"].shape[-1])
            assert env.observation_spec["observation"].shape[-1] == sizes[-1]
            if cfg is advised:
                assert set(td["observation"][-2:].tolist()) <= {0.0, 1.0}
        finally:
            env.close()
        assert ppo.from_config(cfg).obs_dim == sizes[-1]
    assert sizes == [18, 20]
    path = tmp_path / "plain.pt"
    ppo.from_config(plain).save(path)
    with pytest.raises(CheckpointError, match="18 observations.*task.posture_advice=true 2"):
        ppo.from_config(advised).load(path)
