"""The task object: resets at X0, success from the simulated pose, drops, time limits, reward."""

from __future__ import annotations

import numpy as np
import pytest

from inhand_exp.control.grasp import Contacts, Face, Posture
from inhand_exp.task.goal_task import PRESS_M, GoalTask
from inhand_exp.task.goals import GoalPair
from inhand_exp.task.scene import build_scene

L, R = Face.LEFT, Face.RIGHT
BEND = Contacts(Posture((L, L, R)), (-0.21, -0.09, -0.15))
X0 = np.array([0.0, 0.34, 0.0])


@pytest.fixture
def scene(compose_cfg):
    s = build_scene(compose_cfg("task.reward_progress=0.1"))
    yield s
    s.close()


def pairs(*goals) -> list[GoalPair]:
    return [GoalPair("easy", X0.copy(), np.array(g, dtype=float), BEND) for g in goals]


def test_reset_puts_the_object_at_x0_and_once_stops_after_the_goals(scene):
    task = GoalTask(scene, goals=pairs([0.02, 0.34, 0.0], [0.0, 0.36, 0.0]), once=True,
                    max_actions=5)
    rng = np.random.default_rng(0)
    for k in range(2):
        assert task.reset(rng)
        np.testing.assert_allclose(scene.world.object_pose(), X0, atol=1e-9)
        assert task.pair.xg[0] == [0.02, 0.0][k] and task.n_actions == 0
    assert task.exhausted and not task.reset(rng)


def test_success_is_read_from_the_simulated_pose(scene):
    goal = X0 + [0.005, -0.005, 0.05]  # inside the tolerance of X0
    far = X0 + [0.03, 0.0, 0.0]
    task = GoalTask(scene, goals=pairs(goal, far), max_actions=5)
    rng = np.random.default_rng(0)
    task.reset(rng)
    v = task.judge(dropped=False, sim_time_s=0.0)
    assert v.success and v.terminated and not v.truncated
    assert v.reward == pytest.approx(scene.rules.reward_goal)
    task.reset(rng)
    v = task.judge(dropped=False, sim_time_s=0.0)
    assert not v.success and not v.terminated


def test_a_drop_ends_the_episode_even_at_the_goal(scene):
    task = GoalTask(scene, goals=pairs(X0 + [0.005, 0.0, 0.0]), max_actions=5)
    task.reset(np.random.default_rng(0))
    v = task.judge(dropped=True, sim_time_s=0.1)
    assert v.dropped and v.terminated and not v.success and v.reward == 0.0


@pytest.mark.parametrize(("limits", "times", "ends_at"), [
    ({"max_actions": 3}, [0.5] * 5, 3),
    ({"time_limit_s": 1.0}, [0.4] * 5, 3),
    ({"max_actions": 10, "time_limit_s": 0.5}, [0.25] * 5, 2),
])
def test_time_limits_truncate(scene, limits, times, ends_at):
    task = GoalTask(scene, goals=pairs(X0 + [0.04, 0.0, 0.0]), **limits)
    task.reset(np.random.default_rng(0))
    ended = [task.judge(False, t).truncated for t in times]
    assert ended.index(True) + 1 == ends_at


def test_progress_reward_and_invalid_penalty(scene):
    goal = X0 + [0.04, 0.0, 0.0]
    task = GoalTask(scene, goals=pairs(goal), max_actions=9)
    task.reset(np.random.default_rng(0))
    before = task.to_go(X0 + [-0.02, 0.0, 0.0])  # 2 tolerances further than the object now
    v = task.judge(False, 0.5, valid=False, before=before)
    assert v.reward == pytest.approx(0.1 * 2 + scene.rules.reward_invalid)
    assert task.n_invalid == 1 and task.sim_time == 0.5


def test_training_pairs_come_from_the_config_groups_with_fingers_on_the_true_surface(
        compose_cfg):
    cfg = compose_cfg("goals=easy", "goals.train_groups=[medium,hard]", "perturb=thicker")
    scene = build_scene(cfg)
    try:
        task = GoalTask.from_config(scene, cfg)
        assert task.max_actions == cfg.task.max_actions and task.time_limit_s is None
        rng = np.random.default_rng(1)
        groups = set()
        for _ in range(6):
            task.reset(rng)
            groups.add(task.pair.group)
            q = scene.true_model.grasp_q(task.pair.contacts, task.pair.x0, PRESS_M)
            np.testing.assert_allclose(scene.world.joint_q(), q, atol=1e-9)
        assert groups <= {"medium", "hard"} and len(groups) == 2
        e2e = GoalTask.from_config(scene, cfg, end_to_end=True)
        assert e2e.max_actions is None and e2e.time_limit_s == cfg.task.time_limit_s
    finally:
        scene.close()


def test_a_pool_replays_the_first_training_pairs(scene):
    task = GoalTask(scene, groups=("easy",), pool=2, max_actions=5)
    rng = np.random.default_rng(3)
    first = []
    for _ in range(2):
        task.reset(rng)
        first.append(task.pair)
    later = set()
    for _ in range(8):
        task.reset(rng)
        assert any(task.pair is p for p in first)
        later.add(id(task.pair))
    assert len(later) == 2  # both are replayed
