"""The evaluation summary: rates over all episodes and over the subsets the goal set flags."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from inhand_exp.control.grasp import Contacts, Face, Posture
from inhand_exp.learn.evaluate import summarise
from inhand_exp.task.goals import GoalPair

L, R = Face.LEFT, Face.RIGHT
X0, XF = np.array([0.0, 0.34, 0.0]), np.array([0.0, 0.40, 0.0])  # low and high in the hand


def record(success: bool, dropped: bool = False, needs_flip: bool = False,
           lone_down: bool = False, t: float = 3.0) -> dict:
    return {"success": success, "dropped": dropped, "timeout": not (success or dropped),
            "sim_time_s": t, "needs_flip": needs_flip, "lone_down": lone_down}


def test_the_pairs_that_need_a_flip_and_the_others_are_summarised_apart():
    records = [record(True, needs_flip=True, t=10.0), record(False, dropped=True, needs_flip=True),
               record(False, needs_flip=True), record(True), record(True, lone_down=True),
               record(False, dropped=True, lone_down=True)]
    s = summarise(records)
    assert (s["episodes"], s["needs_flip"], s["no_flip"], s["lone_down"]) == (6, 3, 3, 2)
    assert s["needs_flip_success_rate"] == pytest.approx(1 / 3)
    assert s["needs_flip_drop_rate"] == pytest.approx(1 / 3)
    assert s["no_flip_success_rate"] == pytest.approx(2 / 3)
    assert s["no_flip_drop_rate"] == pytest.approx(1 / 3)
    assert s["lone_down_success_rate"] == pytest.approx(1 / 2)
    assert s["success_rate"] == pytest.approx(3 / 6)
    assert s["avg_time_s"] == pytest.approx((10.0 + 3.0 + 3.0) / 3)


def test_without_flagged_pairs_there_is_no_other_subset():
    s = summarise([record(True), record(False)])
    assert (s["needs_flip"], s["no_flip"], s["lone_down"]) == (0, 0, 0)
    assert math.isnan(s["no_flip_success_rate"]) and s["success_rate"] == 0.5


def test_summary_counts_the_episodes_that_flipped_and_their_successes():
    records = [{**record(True, needs_flip=True), "n_flips": 2},
               {**record(False, needs_flip=True), "n_flips": 1},
               {**record(False, needs_flip=True), "n_flips": 0},
               {**record(True), "n_flips": 0}]
    s = summarise(records)
    assert (s["needs_flip_flipped"], s["needs_flip_flipped_success"]) == (2, 1)
    assert (s["no_flip_flipped"], s["flipped"], s["flipped_success"]) == (0, 2, 1)
    assert "flipped" not in summarise([record(True)])  # no counts (DDPG): no figure


def test_an_evaluation_counts_the_flips_its_episodes_made(compose_cfg):
    """A scripted policy flips the right finger where the mask allows it (a grasp with the
    pole held high), else takes the first allowed action: the episode that could flip counts
    its finished flips, as its action records show, the other none."""
    from inhand_exp.envs.batched import batched_env
    from inhand_exp.learn.evaluate import evaluate
    from inhand_exp.task.actions import action_table, flip_actions

    cfg = compose_cfg("task.max_actions=2", "train.backend=serial", "train.workers=1")
    actions = action_table(cfg.primitives)
    names = [a.name for a in actions]
    assert {names[k] for k in flip_actions(actions)} == {"flip left", "flip right"}
    cube = action_table(compose_cfg("object=cube").primitives)
    assert {cube[k].name for k in flip_actions(cube)} == {
        f"land finger {i}{elbow}" for i in range(3) for elbow in ("", " other elbow")}
    flip = names.index("flip right")
    high = Contacts(Posture((L, R, R)), (-0.21, -0.205, -0.15))
    bend = Contacts(Posture((L, L, R)), (-0.21, -0.09, -0.15))
    goals = [GoalPair("hard", XF.copy(), XF + np.array([0.0, 0.0, -0.5]), high),
             GoalPair("easy", X0.copy(), X0 + np.array([0.05, 0.0, 0.0]), bend)]

    def policy(td):
        mask = td["action_mask"]
        return td.set("action", torch.where(mask[..., flip], flip, mask.int().argmax(-1)))

    env = batched_env(cfg, seed=0, goals=goals, num_envs=1, once=True)
    episodes, records = [], []
    summary = evaluate(env, policy, goals, episodes.append, records.append, action_names=names,
                       flip_actions=flip_actions(actions))
    env.close()
    made = [sum(a["name"].startswith("flip") and a["outcome"] == "done"
                for a in records if a["episode"] == k) for k in range(2)]
    assert [e["n_flips"] for e in episodes] == made
    assert made[0] >= 1 and made[1] == 0
    assert (summary["flipped"], summary["flipped_success"]) == (1, 0)
