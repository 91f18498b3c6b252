"""Goal datasets: deterministic, of the right kind, saved and loaded with clear errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from inhand_exp.config import HandConfig, ObjectConfig
from inhand_exp.control.hand import HandModel
from inhand_exp.control.sample import postures as postures_of
from inhand_exp.task.goals import (
    FLIP_FINGERS,
    GoalsError,
    fixed_start,
    flip_distances,
    flip_slot,
    flips_to,
    goal_set,
    holds_near,
    load_goals,
    lone_finger,
    reachable,
    save_goals,
    settable,
    to_frame,
)


@pytest.fixture(scope="module")
def model() -> HandModel:
    return HandModel.from_config(HandConfig(), ObjectConfig(), 9.81)


def test_same_seed_same_set_and_pairs_independent_of_count(model):
    a = to_frame(goal_set(model, "medium", 6, seed=5))
    b = to_frame(goal_set(model, "medium", 6, seed=5))
    assert a.equals(b)
    first = to_frame(goal_set(model, "medium", 3, seed=5))
    assert first.equals(a.iloc[:3])
    assert not a.equals(to_frame(goal_set(model, "medium", 6, seed=6)))


def test_train_and_test_splits_differ(model):
    test = to_frame(goal_set(model, "easy", 5, seed=1, split="test"))
    train = to_frame(goal_set(model, "easy", 5, seed=1, split="train"))
    assert not np.isin(test["xg_x"].to_numpy(), train["xg_x"].to_numpy()).any()


def test_easy_goals_are_reachable_by_reposing_along_the_way(model):
    for p in goal_set(model, "easy", 8, seed=2):
        assert all(reachable(model, p.contacts, p.x0 + (p.xg - p.x0) * s)
                   for s in np.linspace(0, 1, 9))
        assert reachable(model, p.contacts, p.x0)


@pytest.mark.parametrize("group", ["easy", "medium", "hard"])
def test_goals_are_not_already_solved(model, group):
    for p in goal_set(model, group, 8, seed=3):
        d = np.abs(p.xg - p.x0)
        assert max(d[0], d[1]) >= 0.01 or d[2] >= 0.1
        assert p.group == group


def test_hard_sets_need_flips_and_easy_and_medium_sets_never(model):
    """``needs_flip``: no grasp of the initial posture holds the object at the goal."""
    from inhand_exp.control.sample import grasp_of

    hard = goal_set(model, "hard", 24, seed=11)
    flips = [p for p in hard if p.needs_flip]
    assert len(flips) >= 3  # about 28 % of hard pairs on the default workspace
    for p in flips:  # the flag is the feasibility model's own verdict, found again here
        assert grasp_of(model, p.contacts.posture, p.xg) is None
        for d in ([0.009, 0, 0], [0, -0.009, 0], [0, 0, 0.09], [-0.009, 0.009, -0.09]):
            assert grasp_of(model, p.contacts.posture, p.xg + np.array(d)) is None
    for group in ("easy", "medium"):
        assert not any(p.needs_flip for p in goal_set(model, group, 12, seed=11))


def test_medium_pairs_whose_lone_finger_must_end_lower_are_flagged(model):
    """``lone_down``: every grasp of the initial posture that holds the goal has the lone finger
    lower on the pole than at the start (a slide friction forbids on an upright pole)."""
    from inhand_exp.control.sample import grasp_of

    medium = goal_set(model, "medium", 16, seed=11)
    down = [p for p in medium if p.lone_down]
    assert 1 <= len(down) <= 10, len(down)  # about a quarter of the medium pairs
    for p in medium:
        lone = lone_finger(p.contacts.posture)
        start = p.contacts.coords[lone]
        held = grasp_of(model, p.contacts.posture, p.xg)
        if p.lone_down:  # the goal is held, but only lower down
            assert held is None or held.coords[lone] < start - 0.005
            assert grasp_of(model, p.contacts.posture, p.xg, lone_min=start - 0.005) is None
        else:
            assert holds_near(model, p.contacts.posture, p.xg, lone_min=start - 0.005)
    assert not any(p.lone_down for p in goal_set(model, "easy", 8, seed=11))


def test_flips_of_the_left_and_right_fingers_split_the_postures_into_two_families(model):
    """Table I's flips never move the middle finger: from any posture, flips lead to the three
    postures with the middle finger on the same side, within two flips; all three fingers'
    flips join all six."""
    from inhand_exp.control.grasp import Face, Posture

    def changed(a: Posture, b: Posture) -> int:
        return sum(x != y for x, y in zip(a.faces, b.faces, strict=True))

    six = postures_of(model)
    for p in six:
        family = flip_distances(p, FLIP_FINGERS)
        assert set(family) == {q for q in six if q.faces[1] == p.faces[1]}
        assert sorted(family.values()) in ([0, 1, 1], [0, 1, 2])  # a chain of three
        for q, n in family.items():  # each flip moves one finger
            assert n == 0 or any(changed(q, r) == 1 for r, m in family.items() if m == n - 1)
        assert set(flip_distances(p, (0, 1, 2))) == set(six)
        assert flip_distances(p, ()) == {p: 0}
    L, R = Face.LEFT, Face.RIGHT
    assert flip_distances(Posture((L, R, R)), FLIP_FINGERS) == {
        Posture((L, R, R)): 0, Posture((L, R, L)): 1, Posture((R, R, L)): 2}


def test_hard_pairs_are_kept_only_when_the_flips_reach_the_goal(model):
    """The default hard set leaves out pairs whose goal only the other posture family holds;
    ``fingers=None`` keeps them. The pairs the check keeps are the very same draws."""
    kept = goal_set(model, "hard", 24, seed=11)
    every = goal_set(model, "hard", 24, seed=11, fingers=None)
    for p in kept:
        assert flips_to(model, p.contacts.posture, p.xg, FLIP_FINGERS) is not None
    out = [p for p in every if flips_to(model, p.contacts.posture, p.xg, FLIP_FINGERS) is None]
    assert out and all(p.needs_flip for p in out)
    for p in out:  # a grasp with the middle finger on its other side holds the goal
        assert any(holds_near(model, q, p.xg) for q in postures_of(model)
                   if q.faces[1] != p.contacts.posture.faces[1])
    same = sum(np.array_equal(a.xg, b.xg) for a, b in zip(kept, every, strict=True))
    assert same == len(every) - len(out)


def test_the_flip_training_group_draws_hard_pairs_that_need_a_flip(model):
    from inhand_exp.task.goals import sample_pair

    for i in range(3):
        pair = sample_pair(model, "flip", np.random.default_rng([5, i]))
        assert pair.group == "hard" and pair.needs_flip
        assert flips_to(model, pair.contacts.posture, pair.xg, FLIP_FINGERS) > 0
    with pytest.raises(ValueError, match="goal group must be one of"):
        goal_set(model, "flip", 2, seed=1)  # a test set is one of the paper's groups


def test_the_lone_training_group_draws_medium_pairs_whose_lone_finger_must_end_lower(model):
    from inhand_exp.task.goals import lone_descends, sample_pair, with_lone_down

    for i in range(3):
        pair = sample_pair(model, "lone", np.random.default_rng([6, i]))
        assert pair.group == "medium" and pair.lone_down and not pair.needs_flip
        assert lone_descends(model, pair.contacts, pair.xg)
        assert with_lone_down(model, pair) == pair  # the flag a test set would give it
    with pytest.raises(ValueError, match="goal group must be one of"):
        goal_set(model, "lone", 2, seed=1)


def test_a_fixed_start_is_shared_by_every_pair_and_holds(model):
    """``goals.x0`` (the paper's cube study): one start pose and one grasp for every pair."""
    from inhand_exp.control.sample import holds_at

    cube = HandModel.from_config(HandConfig(), ObjectConfig(name="cube", length_m=0.1,
                                                            width_m=0.1), 9.81)
    start = fixed_start(cube, [0.0, 0.25, 0.0], seed=4)
    assert fixed_start(cube, [0.0, 0.25, 0.0], seed=4)[1] == start[1]  # drawn from the seed
    assert holds_at(cube, start[1], start[0]) is not None
    for split in ("test", "train"):
        pairs = goal_set(cube, "hard", 6, seed=4, split=split, hard_posture="any", start=start)
        assert all(np.array_equal(p.x0, [0.0, 0.25, 0.0]) and p.contacts == start[1]
                   for p in pairs)
        assert len({tuple(p.xg) for p in pairs}) == 6  # the goals still vary
    with pytest.raises(GoalsError, match=r"goals.x0=\[0.0, 0.6, 0.0\]: no grasp"):
        fixed_start(cube, [0.0, 0.6, 0.0], seed=4)


def test_a_perturbed_set_starts_on_the_simulated_object_and_keeps_the_pairs_that_fit(model):
    """A longer pole does not fit every nominal grasp at X0 (its lower end reaches the palm):
    those pairs are drawn again, the others stay as they were."""
    from inhand_exp.config import PerturbConfig
    from inhand_exp.task.scene import true_object

    longer = HandModel.from_config(HandConfig(), true_object(
        ObjectConfig(), PerturbConfig("longer", length_scale=1.1)), 9.81)
    fits = settable(longer)
    nominal = goal_set(model, "medium", 16, seed=1234)
    perturbed = goal_set(model, "medium", 16, seed=1234, fits=fits)
    misfits = [i for i, p in enumerate(nominal) if not fits(p)]
    assert misfits and all(fits(p) for p in perturbed)
    for i, (a, b) in enumerate(zip(nominal, perturbed, strict=True)):
        assert np.array_equal(a.xg, b.xg) == (i not in misfits)


def test_a_shorter_pole_draws_again_the_pairs_whose_tip_would_rest_on_its_end(model):
    """The nominal sampler keeps a tip two radii from the nominal ends: where a pole a tenth
    shorter ends. Such a tip reaches the shorter pole (the joints and links allow it) but rests
    on its edge; those pairs are drawn again, and no tip of the set lies on an edge."""
    from inhand_exp.config import PerturbConfig
    from inhand_exp.task.goals import EDGE_M, PRESS_M
    from inhand_exp.task.scene import true_object

    shorter = HandModel.from_config(HandConfig(), true_object(
        ObjectConfig(), PerturbConfig("shorter", length_scale=0.9)), 9.81)
    fits = settable(shorter)
    end = shorter.shape.half_z - EDGE_M
    nominal = goal_set(model, "medium", 24, seed=1234)
    edge = [p for p in nominal if max(map(abs, p.contacts.coords)) > end]
    assert edge and not any(fits(p) for p in edge)
    for p in edge:  # reach and links alone would have let it start there
        assert shorter.grasp_q(p.contacts, p.x0, PRESS_M).shape == (6,)
    perturbed = goal_set(model, "medium", 24, seed=1234, fits=fits)
    assert all(abs(c) <= end for p in perturbed for c in p.contacts.coords)
    redrawn = [not np.array_equal(a.xg, b.xg) for a, b in zip(nominal, perturbed, strict=True)]
    assert sum(redrawn) == len(edge)


@pytest.mark.parametrize("share", [0.25, 0.4, 1.0])
def test_flip_slots_hold_the_share(share):
    for k in (1, 4, 10, 500):
        assert sum(flip_slot(i, share) for i in range(k)) == math.floor(k * share)
    assert not any(flip_slot(i, 0.0) for i in range(100))


def test_a_hard_set_with_a_flip_share_needs_flips_in_its_slots_and_keeps_the_other_pairs(
        model):
    """Every 4th pair of the hard set needs a flip; the others are the pairs of the set
    without the share, and a medium set is not touched."""
    plain = goal_set(model, "hard", 8, seed=1234)
    mixed = goal_set(model, "hard", 8, seed=1234, flip_share=0.25)
    for i, (a, b) in enumerate(zip(plain, mixed, strict=True)):
        if i in (3, 7):
            assert b.needs_flip and b.group == "hard"
            assert not holds_near(model, b.contacts.posture, b.xg)  # by the model, not a flag
        else:
            assert np.array_equal(a.xg, b.xg) and a.contacts == b.contacts
    medium = goal_set(model, "medium", 4, seed=1234, flip_share=0.25)
    assert [p.xg.tolist() for p in medium] == [
        p.xg.tolist() for p in goal_set(model, "medium", 4, seed=1234)]


def test_save_load_round_trip_and_no_overwrite(model, tmp_path):
    pairs = goal_set(model, "hard", 4, seed=4)
    path = save_goals(pairs, tmp_path / "goals.csv")
    back = load_goals(path)
    assert [p.contacts.posture for p in back] == [p.contacts.posture for p in pairs]
    assert [p.needs_flip for p in back] == [p.needs_flip for p in pairs]
    np.testing.assert_allclose([p.xg for p in back], [p.xg for p in pairs], atol=1e-8)
    np.testing.assert_allclose([p.contacts.coords for p in back],
                               [p.contacts.coords for p in pairs], atol=1e-8)
    old = tmp_path / "without_flag.csv"  # a file without the column: the flag is recomputed
    to_frame(pairs).drop(columns=["needs_flip"]).to_csv(old, index=False)
    assert [p.needs_flip for p in load_goals(old, model)] == [p.needs_flip for p in pairs]
    medium = goal_set(model, "medium", 6, seed=11)
    path = save_goals(medium, tmp_path / "medium.csv")
    assert [p.lone_down for p in load_goals(path)] == [p.lone_down for p in medium]
    to_frame(medium).drop(columns=["lone_down"]).to_csv(old := tmp_path / "no_lone.csv",
                                                        index=False)
    assert [p.lone_down for p in load_goals(old, model)] == [p.lone_down for p in medium]
    before = path.read_bytes()
    with pytest.raises(FileExistsError, match="never overwritten"):
        save_goals(pairs, path)
    assert path.read_bytes() == before


@pytest.mark.parametrize(("edit", "message"), [
    (lambda df: df.drop(columns=["xg_z"]), "missing column"),
    (lambda df: df.assign(group="impossible"), "line 2: group must be one of"),
    (lambda df: df.assign(faces="top/side/bottom"), "line 2: faces must be three of"),
    (lambda df: df.assign(x0_x="abc"), "line 2: a pose or contact is not a number"),
    (lambda df: df.assign(c1=float("nan")), "line 2: non-finite"),
    (lambda df: df.assign(needs_flip="maybe"), "line 2: needs_flip must be true or false"),
])
def test_bad_goal_files_name_the_problem(model, tmp_path, edit, message):
    path = tmp_path / "bad.csv"
    edit(to_frame(goal_set(model, "easy", 2, seed=0))).to_csv(path, index=False)
    with pytest.raises(GoalsError, match=message):
        load_goals(path)


def test_missing_and_wrong_kind_of_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="not found"):
        load_goals(tmp_path / "nope.csv")
    (tmp_path / "goals.json").write_text("{}")
    with pytest.raises(GoalsError, match="CSV"):
        load_goals(tmp_path / "goals.json")


def test_parquet_goal_files_load_like_csv(model, tmp_path):
    pairs = goal_set(model, "medium", 3, seed=2)
    path = tmp_path / "goals.parquet"
    to_frame(pairs).to_parquet(path)
    back = load_goals(path)
    assert [p.group for p in back] == ["medium"] * 3
    np.testing.assert_allclose([p.x0 for p in back], [p.x0 for p in pairs])
    assert [p.contacts for p in back] == [p.contacts for p in pairs]
    to_frame(pairs).assign(group="harder").to_parquet(tmp_path / "bad.parquet")
    with pytest.raises(GoalsError, match="row 1: group must be one of"):
        load_goals(tmp_path / "bad.parquet")
    (tmp_path / "cut.parquet").write_bytes(path.read_bytes()[:40])
    with pytest.raises(GoalsError, match="not a readable Parquet file"):
        load_goals(tmp_path / "cut.parquet")
