"""The action table follows the config; the feasibility mask agrees with what execution does."""

from __future__ import annotations

import numpy as np
import pytest

from inhand_exp.control.execute import Observation, execute
from inhand_exp.control.grasp import Contacts, Face, Posture
from inhand_exp.control.hand import HandModel
from inhand_exp.control.sample import random_grasp
from inhand_exp.sim.world import ObjectSpec, World
from inhand_exp.task.actions import action_table, feasibility, make_primitive, undo_actions


def test_pole_table_is_the_papers_fourteen(compose_cfg):
    actions = action_table(compose_cfg().primitives)
    assert len(actions) == 14
    assert [a.index for a in actions] == list(range(14))
    kinds = [a.kind for a in actions]
    assert kinds.count("repose") == 6 and kinds.count("slide") == 6 and kinds.count("flip") == 2
    assert {a.name for a in actions if a.kind == "flip"} == {"flip left", "flip right"}
    assert [a.finger for a in actions if a.kind == "flip"] == [0, 2]


def test_cube_table_has_release_and_land_and_no_slides(compose_cfg):
    actions = action_table(compose_cfg("object=cube", "primitives.land_other_elbow=false")
                           .primitives)
    assert [a.kind for a in actions].count("repose") == 6
    assert sorted((a.kind, a.finger) for a in actions if a.kind in ("release", "land")) == [
        ("land", 0), ("land", 1), ("land", 2), ("release", 0), ("release", 1), ("release", 2)]
    assert len(actions) == 12


def test_cube_table_offers_lands_with_the_other_elbow(compose_cfg):
    actions = action_table(compose_cfg("object=cube").primitives)
    assert len(actions) == 15
    other = [a for a in actions if a.other_elbow]
    assert [(a.kind, a.finger) for a in other] == [("land", 0), ("land", 1), ("land", 2)]
    assert [a.index for a in other] == [12, 13, 14]  # the 12 actions keep their indices
    assert other[1].name == "land finger 1 other elbow"


def test_step_sizes_and_switches_come_from_the_config(compose_cfg):
    prim = compose_cfg("primitives.repose_dx_m=0.02", "primitives.repose_dtheta_rad=0.05",
                       "primitives.slide_dc_m=0.03", "primitives.flip=false").primitives
    actions = action_table(prim)
    assert len(actions) == 12
    by_name = {a.name: a for a in actions}
    assert by_name["repose -x"].delta == (-0.02, 0.0, 0.0)
    assert by_name["repose +theta"].delta == (0.0, 0.0, 0.05)
    assert by_name["slide finger 1 -"].dc == -0.03


@pytest.fixture
def pole_setup(compose_cfg):
    cfg = compose_cfg()
    model = HandModel.from_config(cfg.hand, cfg.object, cfg.sim.gravity_mps2)
    world = World(cfg.sim, cfg.hand, ObjectSpec.from_config(cfg.object))
    yield cfg, model, world
    world.close()


def observe(world: World) -> Observation:
    pose, twist = world.object_state()
    q, qd = world.joint_state()
    return Observation(q, qd, pose, twist, 0.0)


def test_bend_grasp_mask(pole_setup):
    cfg, model, world = pole_setup
    contacts = Contacts(Posture((Face.LEFT, Face.LEFT, Face.RIGHT)), (-0.21, -0.09, -0.15))
    pose = np.array([0.0, 0.34, 0.0])
    world.reset(pose, model.grasp_q(contacts, pose, press=0.0005))
    actions = action_table(cfg.primitives)
    mask, planned = feasibility(actions, model, contacts, cfg.primitives,
                                observe(world))
    kinds = np.array([a.kind for a in actions])
    assert mask[kinds == "repose"].all()  # small reposes of a centred grasp are all reachable
    assert not mask[kinds == "flip"].any()  # fingers 1 and 2 (or 0 and 1) cannot hold alone
    slides = np.array([a.name for a in actions])[mask & (kinds == "slide")]
    assert "slide finger 2 -" not in slides  # the lone finger stays put
    assert "slide finger 0 -" not in slides  # -0.23 is within end_margin_m of the end
    assert len(slides) == 4
    assert all((p is not None) == m for p, m in zip(planned, mask, strict=True))
    reposes = [p for p, a in zip(planned, actions, strict=True) if a.kind == "repose"]
    assert all(p.plan is reposes[0].plan for p in reposes)  # one force plan for the six
    slides = {(a.finger, a.dc): p for p, a in zip(planned, actions, strict=True)
              if a.kind == "slide" and p is not None}
    for (finger, dc), p in slides.items():  # both directions rest on one plan
        other = slides.get((finger, -dc))
        assert other is None or (other.rest is p.rest and other.plan is not p.plan)


@pytest.mark.parametrize("seed", [0, 1])
def test_mask_agrees_with_execution(pole_setup, seed):
    """A masked action is refused by execution before any step, leaving the world as it was;
    an allowed one is carried out (here: one allowed repose and one allowed slide)."""
    cfg, model, world = pole_setup
    pose, contacts, q = random_grasp(model, np.random.default_rng(seed))
    world.reset(pose, q)
    actions = action_table(cfg.primitives)
    obs = observe(world)
    mask, _ = feasibility(actions, model, contacts, cfg.primitives, obs)
    for a in actions:
        if mask[a.index]:
            continue
        out = execute(world, make_primitive(a, model, contacts, cfg.primitives))
        assert out.reason == "infeasible" and out.steps == 0 and out.detail, (a.name, out)
    np.testing.assert_array_equal(world.object_pose(), obs.pose)
    for kind in ("repose", "slide"):
        allowed = [a for a in actions if a.kind == kind and mask[a.index]]
        if allowed:
            out = execute(world, make_primitive(allowed[0], model, contacts, cfg.primitives))
            assert out.steps > 0 and out.reason != "infeasible", (allowed[0].name, out)
            contacts = model.measured(contacts, world.object_pose(), world.joint_q())


def test_each_repose_and_slide_is_undone_by_its_opposite(compose_cfg):
    actions = action_table(compose_cfg().primitives)
    undo = undo_actions(actions)
    names = {a.index: a.name for a in actions}
    pairs = {names[a.index]: names[u] for a, u in zip(actions, undo, strict=True) if u is not None}
    assert pairs["repose +x"] == "repose -x" and pairs["repose -theta"] == "repose +theta"
    assert pairs["slide finger 1 +"] == "slide finger 1 -"
    assert len(pairs) == 12  # 6 reposes and 6 slides; flips have none
    assert all(undo[u] == a.index for a, u in zip(actions, undo, strict=True) if u is not None)


def test_a_flip_is_undone_by_itself_only_when_asked(compose_cfg):
    actions = action_table(compose_cfg().primitives)
    names = {a.index: a.name for a in actions}
    for moves, count in ((False, 2), (True, 14)):
        undo = undo_actions(actions, moves=moves, flips=True)
        pairs = {names[a.index]: names[u] for a, u in zip(actions, undo, strict=True)
                 if u is not None}
        assert pairs["flip left"] == "flip left" and pairs["flip right"] == "flip right"
        assert len(pairs) == count
    cube = action_table(compose_cfg("object=cube").primitives)
    assert set(undo_actions(cube, moves=False, flips=True)) == {None}  # releases and lands
