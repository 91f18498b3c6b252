"""The evaluation summary: rates over all episodes and over the subsets the goal set flags."""

from __future__ import annotations

import math

import pytest

from inhand_exp.learn.evaluate import summarise


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
