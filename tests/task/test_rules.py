"""Success tolerances, rewards and the useful-flip test."""

from __future__ import annotations

import math

import numpy as np
import pytest

from inhand_exp.config import HandConfig, ObjectConfig, TaskConfig, typed
from inhand_exp.control.grasp import Contacts, Face, Posture
from inhand_exp.control.hand import HandModel
from inhand_exp.task.rules import flip_useful, pose_error, reached, reward, to_go


def test_rules_are_the_typed_task_config(compose_cfg):
    rules = typed(compose_cfg("task.reward_goal=7", "task.max_actions=30").task, TaskConfig)
    assert isinstance(rules, TaskConfig)
    assert (rules.reward_goal, rules.max_actions, rules.success_tol_m) == (7.0, 30, 0.01)


@pytest.mark.parametrize(("offset", "ok"), [
    ((0.0099, -0.0099, 0.099), True),
    ((0.0101, 0.0, 0.0), False), ((0.0, -0.0101, 0.0), False), ((0.0, 0.0, 0.101), False),
    ((0.0, 0.0, 2 * math.pi + 0.05), True),  # angles wrap
])
def test_success_tolerances(offset, ok):
    goal = np.array([0.01, 0.2, 0.3])
    assert reached(goal + np.array(offset), goal, TaskConfig()) is ok


def test_pose_error_wraps_the_angle():
    ex, ez, eth = pose_error(np.array([0, 0, 3.1]), np.array([0, 0, -3.1]))
    assert eth == pytest.approx(2 * math.pi - 6.2)


def test_reward_terms_add_up():
    r = TaskConfig()
    assert reward(r, valid=False, success=False, useful_flip=False) == pytest.approx(-0.01)
    assert reward(r, valid=True, success=True, useful_flip=False) == pytest.approx(5.0)
    assert reward(r, valid=True, success=False, useful_flip=True) == pytest.approx(1.0)
    assert reward(r, valid=True, success=False, useful_flip=False) == 0.0
    assert reward(r, valid=True, success=False, useful_flip=False, progress=3.0) == 0.0


def test_progress_shaping_telescopes_to_the_distance_covered():
    rules = TaskConfig(reward_progress=0.1)
    goal = np.array([0.0, 0.2, 0.0])
    path = [np.array([0.05, 0.17, 0.4]), np.array([0.04, 0.18, 0.2]),
            np.array([0.06, 0.18, 0.3]), np.array([0.005, 0.2, 0.05])]
    assert to_go(path[0], goal, rules) == pytest.approx(5 + 3 + 4)
    total = sum(reward(rules, valid=True, success=False, useful_flip=False,
                       progress=to_go(a, goal, rules) - to_go(b, goal, rules))
                for a, b in zip(path, path[1:], strict=False))
    assert total == pytest.approx(0.1 * (to_go(path[0], goal, rules)
                                         - to_go(path[-1], goal, rules)))


def test_flip_useful_follows_the_angle_still_to_go():
    model = HandModel.from_config(HandConfig(), ObjectConfig(), 9.81)
    pose = np.array([0.0, 0.2, 0.0])
    # finger 0 pushes up from below, left of the centre: a clockwise (negative) torque
    contacts = Contacts(Posture((Face.BOTTOM, Face.TOP, Face.BOTTOM)), (-0.12, 0.0, 0.12))
    assert flip_useful(model, contacts, 0, pose, pose + np.array([0, 0, -0.3]))
    assert not flip_useful(model, contacts, 0, pose, pose + np.array([0, 0, 0.3]))
    # pushing down from above on the same side turns the other way
    flipped = contacts.moved(0, face=Face.TOP)
    assert flip_useful(model, flipped, 0, pose, pose + np.array([0, 0, 0.3]))
