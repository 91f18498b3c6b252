"""``task.reach``: the cube's reachable states by reposes, releases and lands."""

from __future__ import annotations

import numpy as np
import pytest

from inhand_exp.config import HandConfig, ObjectConfig, PrimitivesConfig, SimConfig
from inhand_exp.control.grasp import Face, Posture
from inhand_exp.control.hand import HandModel
from inhand_exp.control.sample import grasp_of
from inhand_exp.task.reach import Reach

CUBE = ObjectConfig(name="cube", length_m=0.1, width_m=0.1, mass_kg=0.1)
UPRIGHT = np.array([0.0, 0.25, 0.0])
LBR = Posture((Face.LEFT, Face.BOTTOM, Face.RIGHT))


@pytest.fixture(scope="module")
def model() -> HandModel:
    return HandModel.from_config(HandConfig(), CUBE, SimConfig().gravity_mps2)


@pytest.fixture(scope="module")
def reach(model) -> Reach:
    start = grasp_of(model, LBR, UPRIGHT)
    assert start is not None
    r = Reach.lattice(model, PrimitivesConfig(), 0.0, (0.23, 0.27), (-0.3, 0.3), 0.02, 0.1,
                      opposite_only=True)
    return r.search(UPRIGHT, start)


def test_the_search_reaches_the_start_and_releases_only_fingers_with_opposing_partners(reach):
    start = (LBR, -1, *reach.cell(UPRIGHT))
    assert start in reach.reached
    lifted = {(p, k) for p, k, _, _ in reach.reached if k >= 0}
    assert (LBR, 1) in lifted  # left and right hold the cube alone
    for p, k in lifted:  # every two-finger state stands on a pair of opposite faces
        a, b = (p.faces[j] for j in range(3) if j != k)
        assert {a, b} in ({Face.LEFT, Face.RIGHT}, {Face.TOP, Face.BOTTOM})
    assert not reach.held((LBR, 0, *reach.cell(UPRIGHT)))  # bottom and right do not oppose


def test_lands_change_the_posture_and_every_reached_state_holds(reach, model):
    postures = {p for p, k, _, _ in reach.reached if k < 0}
    assert len(postures) > 1  # a release and a land on another face change the posture
    for p, k, iz, it in reach.reached:
        if k < 0:
            assert grasp_of(model, p, reach.pose(iz, it), tries=reach.tries) is not None
    lifted = (LBR, 1, *reach.cell(UPRIGHT))
    landed = [m[0].faces[1] for m in reach._moves(lifted) if m[1] < 0]
    assert Face.BOTTOM not in landed and len(landed) == 3


def test_goals_outside_the_lattice_angles_are_not_reached(reach):
    assert reach.goal_reached(UPRIGHT)
    lo, hi = reach.angles()
    assert -0.3 - 1e-9 <= lo <= hi <= 0.3 + 1e-9
    assert reach.cell(np.array([0.0, 0.25, 1.4])) is None  # off the lattice: never reached
    assert not reach.goal_reached(np.array([0.0, 0.25, 1.4]))


def test_resolutions_must_be_positive(model):
    with pytest.raises(ValueError, match="resolution_rad must be > 0"):
        Reach.lattice(model, PrimitivesConfig(), 0.0, (0.2, 0.3), (-1, 1), 0.02, 0.0)


def test_adjacent_pairs_carry_the_cube_unless_opposite_only(model):
    """Bottom and right hold the upright cube still by their forces (the bottom tip bears the
    weight): they carry it unless ``opposite_only``; two tips on one face never do."""
    args = (model, PrimitivesConfig(), 0.0, (0.23, 0.27), (-0.3, 0.3), 0.02, 0.1)
    strict, loose = Reach.lattice(*args, opposite_only=True), Reach.lattice(*args)
    cell = strict.cell(UPRIGHT)
    assert not strict.held((LBR, 0, *cell)) and loose.held((LBR, 0, *cell))
    same = Posture((Face.BOTTOM, Face.BOTTOM, Face.RIGHT))
    assert not loose.held((same, 2, *cell))
