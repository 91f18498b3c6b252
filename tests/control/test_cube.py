"""Cube primitives (paper section IV-D): hold, repose, release and land, judged from the sim."""

from __future__ import annotations

import numpy as np
import pytest

from inhand_exp.config import HandConfig, ObjectConfig, SimConfig
from inhand_exp.control.execute import Observation, execute
from inhand_exp.control.grasp import Contacts, Face, Posture
from inhand_exp.control.hand import HandModel
from inhand_exp.control.release_land import Land, Release
from inhand_exp.control.repose import Repose
from inhand_exp.control.sample import random_grasp
from inhand_exp.sim.world import ObjectSpec, World

CUBE = ObjectConfig(name="cube", length_m=0.1, width_m=0.1, mass_kg=0.1)


@pytest.fixture(scope="module")
def cube_model() -> HandModel:
    return HandModel.from_config(HandConfig(), CUBE, SimConfig().gravity_mps2)


@pytest.fixture
def cube_world(cube_model):
    world = World(SimConfig(), HandConfig(), ObjectSpec.from_config(CUBE))
    yield world
    world.close()


def observe(world: World) -> Observation:
    pose, twist = world.object_state()
    q, qd = world.joint_state()
    return Observation(q, qd, pose, twist, 0.0)


def touching(world: World) -> set[int]:
    return {c.finger for c in world.contacts()}


def releasable(model: HandModel, world: World, seed: int) -> tuple[Contacts, int, Release]:
    """A seeded random cube grasp and a finger whose release the primitive allows."""
    rng = np.random.default_rng(seed)
    for _ in range(50):
        pose, contacts, q = random_grasp(model, rng)
        world.reset(pose, q)
        for finger in range(3):
            prim = Release(model, contacts, finger, 1.0)
            if prim.start(observe(world)) is None:
                return contacts, finger, prim
    raise AssertionError("no releasable grasp found")


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_cube_grasp_holds_and_reposes(cube_model, cube_world, seed):
    pose, contacts, q = random_grasp(cube_model, np.random.default_rng(seed))
    cube_world.reset(pose, q)
    out = execute(cube_world, Repose(cube_model, contacts, np.zeros(3), 2.0))
    assert out.reason == "done", out
    assert np.abs(cube_world.object_pose() - pose).max() < 1e-3
    delta = np.array([0.01, 0.0, 0.0])
    out = execute(cube_world, Repose(cube_model, contacts, delta, 0.5))
    if out.reason == "infeasible":  # target out of reach: refused before any step
        assert out.steps == 0
        return
    assert out.reason == "done", out
    err = cube_world.object_pose() - (pose + delta)
    assert np.hypot(*err[:2]) < 2e-3 and abs(err[2]) < 0.02
    assert touching(cube_world) == {0, 1, 2}


@pytest.mark.parametrize("seed", [10, 11, 12])
def test_release_then_land_on_another_face(cube_model, cube_world, seed):
    """Released grasps (seeds from ``seed`` on) until one has a landing: it puts the finger on
    another face than the one it left, and the three fingers then hold the cube."""
    for s in range(seed, seed + 8):
        contacts, finger, release = releasable(cube_model, cube_world, s)
        start = cube_world.object_pose()
        out = execute(cube_world, release)
        assert out.reason == "done", out
        assert touching(cube_world) == {0, 1, 2} - {finger}  # lifted off, the pair holds
        assert np.hypot(*(cube_world.object_pose() - start)[:2]) < 3e-3
        land = Land(cube_model, release.result, finger, 1.5)
        refused = land.start(observe(cube_world))
        if refused is None:
            break
        assert "no reachable landing" in refused
    else:
        pytest.fail("no landing found after 8 releases")
    assert land.face != contacts.posture.faces[finger]  # a new side: the second half of a flip
    out = execute(cube_world, land)
    assert out.reason == "done", out
    assert touching(cube_world) == {0, 1, 2}
    # the landed finger pushes on the face it was sent to (normal from PyBullet's contacts)
    (c,) = [c for c in cube_world.contacts() if c.finger == finger]
    pose = cube_world.object_pose()
    inward = {Face.TOP: (0, -1), Face.BOTTOM: (0, 1), Face.RIGHT: (-1, 0), Face.LEFT: (1, 0)}
    R = np.array([[np.cos(pose[2]), -np.sin(pose[2])], [np.sin(pose[2]), np.cos(pose[2])]])
    assert float(c.normal @ (R @ np.array(inward[land.face]))) > 0.95
    hold = execute(cube_world, Repose(cube_model, land.result, np.zeros(3), 1.0))
    assert hold.reason == "done", hold


def test_two_fingers_on_adjacent_faces_carry_the_cube(cube_model, cube_world):
    """A release whose staying pair is on adjacent faces (a corner hold): the cube stays put on
    the two tips, and the drop test counts it held."""
    rng = np.random.default_rng(5)
    for _ in range(200):
        pose, contacts, q = random_grasp(cube_model, rng)
        cube_world.reset(pose, q)
        for finger in range(3):
            a, b = (contacts.posture.faces[j] for j in range(3) if j != finger)
            if {a, b} in ({Face.LEFT, Face.RIGHT}, {Face.TOP, Face.BOTTOM}):
                continue  # opposite faces: the case every object allows
            release = Release(cube_model, contacts, finger, 1.0)
            if release.start(observe(cube_world)) is None:
                break
        else:
            continue
        break
    else:
        pytest.fail("no release onto adjacent faces found in 200 grasps")
    start = cube_world.object_pose()
    out = execute(cube_world, release)
    assert out.reason == "done", out
    assert touching(cube_world) == {0, 1, 2} - {finger}
    assert cube_world.grasp_lost() is None
    assert np.hypot(*(cube_world.object_pose() - start)[:2]) < 3e-3


def test_release_needs_a_pair_on_two_faces(cube_model, cube_world):
    # fingers 1 and 2 both on the bottom face cannot hold the cube without finger 0; the
    # cube sits high enough for both to reach under it with their links clear
    contacts = Contacts(Posture((Face.LEFT, Face.BOTTOM, Face.BOTTOM)), (0.0, -0.02, 0.02))
    pose = np.array([0.0, 0.25, 0.0])
    cube_world.reset(pose, cube_model.grasp_q(contacts, pose, press=0.0005))
    out = execute(cube_world, Release(cube_model, contacts, 0, 1.0))
    assert out.reason == "infeasible" and out.steps == 0
    assert "on one face" in out.detail


def test_land_refuses_a_finger_in_contact(cube_model, cube_world):
    contacts, finger, _ = releasable(cube_model, cube_world, 10)
    out = execute(cube_world, Land(cube_model, contacts, finger, 1.5))
    assert out.reason == "infeasible" and "already in contact" in out.detail


def study_start(model: HandModel, world: World) -> Contacts:
    """The cube study's start (``goals.x0=[0, 0.25, 0]``, its grasp drawn from the default goal
    seed: bottom finger 2.5 cm off centre), set in ``world``."""
    contacts = Contacts(Posture((Face.LEFT, Face.BOTTOM, Face.RIGHT)), (0.005, 0.025, 0.015))
    pose = np.array([0.0, 0.25, 0.0])
    world.reset(pose, model.grasp_q(contacts, pose, press=0.0005))
    return contacts


def test_a_free_finger_holds_still_while_the_others_turn_the_cube(cube_model, cube_world):
    """The cube study's start (bottom finger off centre), its bottom finger released, then the
    cube turned 0.5 rad on the side fingers: the free finger holds its joints where the release
    left it (it used to fall limp to its joint limits, from where no landing reached the cube),
    the cube is never touched by it, and it lands again on another face."""
    contacts = study_start(cube_model, cube_world)
    release = Release(cube_model, contacts, 1, 1.0)
    assert execute(cube_world, release).reason == "done"
    held = contacts.moved(1, active=False)
    q_free = cube_world.joint_state()[0][2:4]
    for _ in range(5):
        out = execute(cube_world, Repose(cube_model, held, np.array([0.0, 0.0, -0.1]), 0.5))
        assert out.reason == "done", out
        assert np.abs(cube_world.joint_state()[0][2:4] - q_free).max() < 0.02
        assert touching(cube_world) == {0, 2}
    assert cube_world.object_pose()[2] < -0.4
    land = Land(cube_model, held, 1, 1.5)
    out = execute(cube_world, land)
    assert out.reason == "done", out
    assert land.face != Face.BOTTOM and touching(cube_world) == {0, 1, 2}


def test_a_land_with_the_other_elbow_opens_the_other_quarter_turn(cube_model, cube_world):
    """From the study's start the bottom finger's elbow is to the right of its tip, and its
    links meet the cube when it turns -theta. Released and put down with the other elbow (its
    joints go round through the straight finger, never touching the cube), it lands at its
    mirror image, left of the face's centre; the left finger can then be released, and the
    bottom and right fingers turn the cube a quarter turn the other way without dropping it."""
    contacts = study_start(cube_model, cube_world)
    assert cube_world.joint_state()[0][3] > 0  # the elbow to the right of the tip
    assert Release(cube_model, contacts, 0, 1.0).start(observe(cube_world)) is not None
    assert execute(cube_world, Release(cube_model, contacts, 1, 1.0)).reason == "done"
    held = contacts.moved(1, active=False)
    land = Land(cube_model, held, 1, 1.5, other_elbow=True)
    out = execute(cube_world, land)
    assert out.reason == "done", out
    assert land.face == Face.BOTTOM and land.coord < -0.01
    assert cube_world.joint_state()[0][3] < 0 and touching(cube_world) == {0, 1, 2}
    assert np.abs(cube_world.object_pose() - [0.0, 0.25, 0.0]).max() < 0.01
    grasp = land.result
    assert execute(cube_world, Release(cube_model, grasp, 0, 1.0)).reason == "done"
    pair = grasp.moved(0, active=False)
    while cube_world.object_pose()[2] > -1.45:
        out = execute(cube_world, Repose(cube_model, pair, np.array([0.0, 0.0, -0.1]), 0.5))
        assert out.reason == "done" and not out.dropped, out
        assert touching(cube_world) == {1, 2}
    assert abs(cube_world.object_pose()[2] + 1.5) < 0.1


def test_a_turn_that_would_sweep_a_corner_into_the_free_tip_is_refused(cube_model, cube_world):
    """A cube's corners sweep out to half its diagonal as it turns. With the right finger
    lifted only 2 cm off its face, its tip lies inside that sweep: the turns on the other two
    stop before the corner reaches it, and the free finger is never touched (they used to go
    on, brushing the corner past the tip; the release now lifts 2.5 cm and the turn goes
    through, see ``test_a_land_with_the_other_elbow_opens_the_other_quarter_turn``)."""
    contacts = study_start(cube_model, cube_world)
    release = Release(cube_model, contacts, 2, 1.0, clearance_m=0.02)
    assert execute(cube_world, release).reason == "done"
    pair = contacts.moved(2, active=False)
    for _ in range(15):
        out = execute(cube_world, Repose(cube_model, pair, np.array([0.0, 0.0, 0.1]), 0.5))
        assert 2 not in touching(cube_world)
        if out.reason != "done":
            break
    assert out.reason == "infeasible" and "free finger 2" in out.detail, out
    assert 0.5 < cube_world.object_pose()[2] < 0.9  # about where a corner points at it


def test_a_turn_into_the_free_finger_is_refused(cube_model, cube_world):
    """A move that would bring the cube within the clearance of the released finger is refused
    before any step."""
    contacts = study_start(cube_model, cube_world)
    assert execute(cube_world, Release(cube_model, contacts, 1, 1.0)).reason == "done"
    held = contacts.moved(1, active=False)
    out = execute(cube_world, Repose(cube_model, held, np.array([0.0, -0.03, 0.0]), 0.5))
    assert out.reason == "infeasible" and out.steps == 0, out
    assert "free finger 1" in out.detail


def test_a_turn_the_grasp_cannot_hold_at_its_end_is_refused(cube_model, cube_world):
    """On two tips at a corner (the study's start without its right finger) the cube turns
    -0.1 rad at a time until gravity, turned in the cube's frame, leaves the pair no forces
    that hold it at the next angle: that turn is refused before any step (it used to be taken,
    and the cube fell), and the cube was never dropped on the way."""
    contacts = study_start(cube_model, cube_world)
    assert execute(cube_world, Release(cube_model, contacts, 2, 1.0)).reason == "done"
    held = contacts.moved(2, active=False)
    for _ in range(8):
        out = execute(cube_world, Repose(cube_model, held, np.array([0.0, 0.0, -0.1]), 0.5))
        assert not out.dropped, out
        if out.reason == "infeasible":
            break
        assert out.reason == "done", out
    assert out.steps == 0 and "at the target angle" in out.detail, out
    assert cube_world.object_pose()[2] < -0.25 and cube_world.grasp_lost() is None
