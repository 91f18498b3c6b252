"""Hostile goal files, generated at random: every one loads or is refused with a GoalsError."""

from __future__ import annotations

import numpy as np
import pytest

from inhand_exp.config import HandConfig, ObjectConfig
from inhand_exp.control.hand import HandModel
from inhand_exp.task.goals import GoalsError, goal_set, load_goals, to_frame

JUNK = ["", "nan", "inf", "-1e308", "abc", "left/left", "left/right/up", "TRUE", "2", "0.5",
        "\x00", "é", "1,2", '"', "-0.0", "1e-400"]


@pytest.fixture(scope="module")
def model() -> HandModel:
    return HandModel.from_config(HandConfig(), ObjectConfig(), 9.81)


@pytest.fixture(scope="module")
def good(model):
    return to_frame(goal_set(model, "easy", 3, seed=9) + goal_set(model, "hard", 2, seed=9))


def mutate(frame, rng: np.random.Generator):
    """One random corruption: cells replaced by junk or random numbers, columns dropped,
    renamed or shuffled, rows duplicated."""
    f = frame.copy().astype(object)
    kind = rng.integers(5)
    if kind == 0:
        for _ in range(rng.integers(1, 4)):
            f.iat[rng.integers(len(f)), rng.integers(f.shape[1])] = JUNK[rng.integers(len(JUNK))]
    elif kind == 1:
        for _ in range(rng.integers(1, 4)):
            f.iat[rng.integers(len(f)), rng.integers(1, 7)] = float(rng.normal(0, 3))
    elif kind == 2:
        f = f.drop(columns=f.columns[rng.integers(f.shape[1])])
    elif kind == 3:
        cols = list(f.columns)
        rng.shuffle(cols)
        f.columns = cols
    else:
        f = f.iloc[rng.integers(len(f), size=rng.integers(0, 8))]
    return f


def test_random_corruptions_load_or_are_refused_by_line(tmp_path, good, model):
    rng = np.random.default_rng(2026)
    outcomes = {"loaded": 0, "refused": 0}
    for i in range(60):
        path = tmp_path / f"g{i}.csv"
        mutate(good, rng).to_csv(path, index=False)
        try:
            pairs = load_goals(path, model)
        except GoalsError as err:
            outcomes["refused"] += 1
            assert str(path) in str(err)
        else:
            outcomes["loaded"] += 1
            assert all(np.isfinite(np.r_[p.x0, p.xg, p.contacts.coords]).all() for p in pairs)
    assert outcomes["refused"] > 10 and outcomes["loaded"] > 5, outcomes


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_random_bytes_are_refused(tmp_path, suffix, model):
    rng = np.random.default_rng(7)
    for i in range(15):
        path = tmp_path / f"b{i}{suffix}"
        path.write_bytes(rng.bytes(int(rng.integers(0, 400))))
        with pytest.raises(GoalsError):
            load_goals(path, model)
