"""The PyBullet world: integration, planar constraint, torque control, determinism, contacts."""

from __future__ import annotations

import numpy as np
import pybullet as pb
import pytest

from inhand_exp.config import HandConfig, ObjectConfig, PerturbConfig, PrimitivesConfig, SimConfig
from inhand_exp.control.execute import Observation
from inhand_exp.control.grasp import Contacts, Face, Posture
from inhand_exp.control.hand import GeometryError, HandModel
from inhand_exp.control.repose import GraspPlan, Repose, min_jerk, repose_torques
from inhand_exp.sim.world import BODY_LINK, TIP_LINK, ObjectSpec, World

# one ``World.step`` is one physics step here: the tests check the integration step by step
SIM, HAND, OBJ = SimConfig(control_substeps=1), HandConfig(), ObjectConfig()
G_ACC = SIM.gravity_mps2
# the upright pole held in a three-point bend: finger 2 alone on the right side, between the
# other two along the pole; every link clear of it
BEND = Contacts(Posture((Face.LEFT, Face.LEFT, Face.RIGHT)), (-0.21, -0.09, -0.15))
POSE = np.array([0.0, 0.34, 0.0])
FAR = np.array([2.0, 0.2, 0.3])  # object pose well out of the fingers' reach (0.32 m)
Q_FREE = np.array([0.5, 0.5, 1.5, 0.3, 2.0, -0.5])


def _world(obj: ObjectSpec | None = None) -> World:
    return World(SIM, HAND, obj or ObjectSpec.from_config(OBJ))


@pytest.fixture
def world():
    w = _world()
    yield w
    w.close()


@pytest.fixture(scope="module")
def model() -> HandModel:
    return HandModel.from_config(HAND, OBJ, G_ACC)


def test_free_fall_is_semi_implicit_euler(world):
    world.reset(FAR, Q_FREE)
    dt, zs = world.dt, []
    for _ in range(100):
        world.step(np.zeros(6))
        pose, twist = world.object_state()
        zs.append(pose[1])
        assert pose[0] == FAR[0] and pose[2] == FAR[2]
        assert twist[0] == 0.0 and twist[2] == 0.0
    n = np.arange(1, 101)
    np.testing.assert_allclose(zs, FAR[1] - G_ACC * dt**2 * n * (n + 1) / 2, rtol=1e-9,
                               atol=1e-12)
    np.testing.assert_allclose(world.object_state()[1][1], -G_ACC * dt * 100, rtol=1e-9)
    assert world.contacts() == []


def _assert_planar(world: World) -> None:
    pose = world.object_pose()
    pos, orn = pb.getLinkState(world.object, BODY_LINK, computeForwardKinematics=1,
                               physicsClientId=world.client)[4:6]
    assert abs(pos[1]) < 1e-9
    # the link state comes back in single precision: compare in-plane values to 1e-6
    np.testing.assert_allclose([pos[0], pos[2]], pose[:2], rtol=0, atol=1e-6)
    assert abs(orn[0]) < 1e-9 and abs(orn[2]) < 1e-9  # a rotation about y only
    R = np.array(pb.getMatrixFromQuaternion(orn)).reshape(3, 3)
    c, s = np.cos(pose[2]), np.sin(pose[2])
    np.testing.assert_allclose(R[:, 0], [c, 0.0, s], atol=1e-6)  # CCW about -y by theta
    np.testing.assert_allclose(R[:, 1], [0.0, 1.0, 0.0], atol=1e-9)


def test_object_stays_in_plane_under_random_torques(world, model):
    world.reset(POSE, model.grasp_q(BEND, POSE, press=0.0005))
    rng = np.random.default_rng(3)
    moved = 0.0
    for _ in range(200):
        world.step(rng.uniform(-0.5, 0.5, 6))
        _assert_planar(world)
        moved = max(moved, float(np.abs(world.object_pose() - POSE).max()))
    assert moved > 0.01  # the fingers really pushed the object around


def test_torque_control_initial_acceleration(world, model):
    world.reset(FAR, Q_FREE)
    tau = np.array([0.05, -0.02, -0.03, 0.04, 0.02, 0.01])
    world.step(tau)
    qd = world.joint_qd()
    for i, finger in enumerate(model.fingers):
        q0, t = Q_FREE[2 * i:2 * i + 2], tau[2 * i:2 * i + 2]
        qdd = np.linalg.solve(finger.mass_matrix(q0), t - finger.gravity_torque(q0))
        np.testing.assert_allclose(qd[2 * i:2 * i + 2] / world.dt, qdd, rtol=1e-3)


def test_torque_is_clipped_to_limit(model):
    """A command beyond max_torque_nm acts like the limit itself (a small limit keeps the
    joints below the URDF's 100 rad/s velocity cap, which PyBullet also enforces)."""
    limit = 0.05
    w = World(SIM, HandConfig(max_torque_nm=limit), ObjectSpec.from_config(OBJ))
    try:
        w.reset(FAR, Q_FREE)
        cmd = np.array([1.0, -1.0, 0.2, 0.03, -5.0, -0.01])
        w.step(cmd)
        qd = w.joint_qd()
        for i, finger in enumerate(model.fingers):
            q0, t = Q_FREE[2 * i:2 * i + 2], np.clip(cmd[2 * i:2 * i + 2], -limit, limit)
            qdd = np.linalg.solve(finger.mass_matrix(q0), t - finger.gravity_torque(q0))
            np.testing.assert_allclose(qd[2 * i:2 * i + 2] / w.dt, qdd, rtol=1e-3)
    finally:
        w.close()


def test_deterministic(model):
    q0 = model.grasp_q(BEND, POSE, press=0.0005)
    runs = []
    for _ in range(2):
        w = _world()
        w.reset(POSE, q0)
        rng = np.random.default_rng(7)
        for _ in range(500):
            w.step(rng.uniform(-0.3, 0.3, 6))
        runs.append((*w.object_state(), *w.joint_state()))
        w.close()
    for a, b in zip(*runs, strict=True):
        np.testing.assert_array_equal(a, b)
    assert np.abs(runs[0][0] - POSE).max() > 1e-3  # the run did something


def test_hold_contacts_balance_gravity(world, model):
    q0 = model.grasp_q(BEND, POSE, press=0.0005)
    world.reset(POSE, q0)
    gains = PrimitivesConfig()
    plan = GraspPlan.from_state(model, BEND, POSE, q0, gains)

    def hold(steps: int) -> None:
        for _ in range(steps):
            q, qd = world.joint_state()
            pose, twist = world.object_state()
            tau = repose_torques(model, plan, gains, q, qd, pose, twist,
                                 min_jerk(POSE, POSE, 1.0, world.time_s))
            assert tau is not None
            world.step(tau)

    def check_normals() -> list:
        cs = sorted(world.contacts(), key=lambda c: c.finger)
        assert [c.finger for c in cs] == [0, 1, 2]
        for c in cs:
            # inward: a finger on the left side pushes along +x, on the right along -x
            inward = 1.0 if BEND.posture.faces[c.finger] == Face.LEFT else -1.0
            np.testing.assert_allclose(c.normal, [inward, 0.0], atol=1e-3)
            assert c.normal_force > 0
        return cs

    hold(3)
    check_normals()
    hold(round(1.0 / world.dt) - 3)
    cs = check_normals()
    pose = world.object_pose()
    np.testing.assert_allclose(pose, POSE, atol=1e-3)  # held still
    force = sum(c.normal_force * c.normal + c.tangential_force * c.tangent for c in cs)
    weight = OBJ.mass_kg * G_ACC
    # upright, the weight runs along the pole: friction alone carries it
    np.testing.assert_allclose(force, [0.0, weight], rtol=0, atol=0.05 * weight)
    assert world.hand_contacts() == []  # the links and the palm stay clear
    torque = 0.0
    for c in cs:
        (rx, rz), (fx, fz) = c.position - pose[:2], c.normal_force * c.normal + \
            c.tangential_force * c.tangent
        torque += rx * fz - rz * fx
    assert abs(torque) < 0.05 * weight * 0.12
    # each contact lies on the face of its finger, a tip radius from the tip centre
    tips = world.tip_positions()
    for c in cs:
        np.testing.assert_allclose(c.position, tips[c.finger] + HAND.tip_radius_m * c.normal,
                                   atol=1e-3)


def test_perturbation_scales_simulated_body():
    spec = ObjectSpec.from_config(OBJ, PerturbConfig(mass_scale=1.1, width_scale=0.5,
                                                     length_scale=1.1))
    w = _world(spec)
    try:
        info = pb.getDynamicsInfo(w.object, BODY_LINK, physicsClientId=w.client)
        assert info[0] == pytest.approx(1.1 * OBJ.mass_kg, rel=1e-12)
        length, width = 1.1 * OBJ.length_m, 0.5 * OBJ.width_m
        iyy = 1.1 * OBJ.mass_kg * (length**2 + width**2) / 12
        assert info[2][1] == pytest.approx(iyy, rel=1e-9)
        (shape,) = pb.getCollisionShapeData(w.object, BODY_LINK, physicsClientId=w.client)
        assert shape[2] == pb.GEOM_BOX
        # width along the object's x, length along its z: the pole stands upright at theta 0
        np.testing.assert_allclose(shape[3], [width, OBJ.depth_m, length], rtol=1e-9)
    finally:
        w.close()


def test_default_object_is_unscaled(world):
    info = pb.getDynamicsInfo(world.object, BODY_LINK, physicsClientId=world.client)
    assert info[0] == pytest.approx(OBJ.mass_kg, rel=1e-12)
    (shape,) = pb.getCollisionShapeData(world.object, BODY_LINK, physicsClientId=world.client)
    np.testing.assert_allclose(shape[3], [OBJ.width_m, OBJ.depth_m, OBJ.length_m], rtol=1e-9)


@pytest.mark.parametrize("link, name, z", [(0, "proximal", 0.08), (1, "distal", 0.24)])
def test_link_moved_into_object_makes_contact(link, name, z):
    """Finger 1 points straight up; the pole, lying across it (theta = pi/2), cuts through its
    proximal (z 0-0.16) or distal (z 0.16-0.32) link, clear of the tip. The simulator reports
    that link touching the object, and no fingertip contact, right after the reset and after a
    step."""
    q = np.array([np.pi, 0.0, np.pi / 2, 0.0, 0.0, 0.0])  # fingers 0 and 2 flat along the palm
    pose = np.array([0.0, z, np.pi / 2])
    w = _world()
    try:
        w.reset(pose, q)
        cid, finger = w.client, w.fingers[1]
        overlap = pb.getClosestPoints(w.object, finger, 0.0, BODY_LINK, link,
                                      physicsClientId=cid)
        assert overlap and min(p[8] for p in overlap) < -0.01
        assert not pb.getClosestPoints(w.object, finger, 0.0, BODY_LINK, TIP_LINK,
                                       physicsClientId=cid)  # the tip is clear
        assert w.hand_contacts() == [f"finger 1 {name}"]
        assert w.contacts() == []  # no fingertip contact, finger 1's included
        w.step(np.zeros(6))
        assert pb.getContactPoints(w.object, finger, BODY_LINK, link, physicsClientId=cid)
        assert w.hand_contacts() == [f"finger 1 {name}"]
        assert w.contacts() == []
    finally:
        w.close()


# every finger resting on a joint limit, its distal link hanging, all well clear of a pole
# standing between the bases of fingers 1 and 2: at rest under gravity with zero torques
_LO, _HI = HAND.joint_lower_rad[0], HAND.joint_upper_rad[0]
Q_AWAY = np.array([_HI, 3 * np.pi / 2 - _HI, _HI, 3 * np.pi / 2 - _HI, _LO, -np.pi / 2 - _LO])
BETWEEN_X = 0.06  # between the bases of fingers 1 (x = 0) and 2 (x = 0.12)


def test_object_overlapping_the_palm_touches_it(world, model):
    """The pole's lower end 5 mm into the palm plate: the simulator reports the palm touching
    it (and nothing else), and the controllers' model refuses a grasp there."""
    pose = np.array([BETWEEN_X, OBJ.length_m / 2 - 0.005, 0.0])
    assert model.palm_gap(pose) == pytest.approx(-0.005)
    world.reset(pose, Q_AWAY)
    assert world.hand_contacts() == ["palm"]
    assert world.contacts() == []
    with pytest.raises(GeometryError, match="palm"):
        model.grasp_q(BEND, pose)


@pytest.mark.parametrize("theta", [0.4, -0.4])
def test_palm_contact_points_lie_on_the_tilted_poles_lower_end(world, model, theta):
    """The tilted pole's lowest corner 3 mm into the palm: every contact point the palm
    reports lies at the pole's end, half its length from the centre along its axis, in the
    model's frame (the sign convention of theta is the model's)."""
    from inhand_exp.control.execute import along_axis
    half_x, half_z = model.shape.half_x, model.shape.half_z
    z = half_z * np.cos(theta) + half_x * np.sin(abs(theta)) - 0.003
    pose = np.array([BETWEEN_X, z, theta])
    assert model.palm_gap(pose) == pytest.approx(-0.003)
    world.reset(pose, Q_AWAY)
    points = world.hand_contact_points()
    assert points and {name for name, _ in points} == {"palm"}
    for _, at in points:
        assert at[1] == pytest.approx(-0.003, abs=1e-3)  # the corner, 3 mm into the palm
        assert along_axis(at, pose) == pytest.approx(half_z, abs=2e-3)


def test_unheld_pole_dropped_comes_to_rest_on_the_palm(world, model):
    """Dropped upright from 5 cm above the palm, fingers out of the way, the pole lands on its
    lower end and stands on the palm: it neither sinks through nor bounces off."""
    start = np.array([BETWEEN_X, OBJ.length_m / 2 + 0.05, 0.0])
    world.reset(start, Q_AWAY)
    assert world.hand_contacts() == [] and model.palm_gap(start) == pytest.approx(0.05)
    for _ in range(round(1.0 / world.dt)):
        world.step(np.zeros(6))
        assert model.palm_gap(world.object_pose()) > -2e-3  # never through the palm
    pose, twist = world.object_state()
    assert world.hand_contacts() == ["palm"]
    assert world.contacts() == []
    np.testing.assert_allclose(pose, [BETWEEN_X, OBJ.length_m / 2, 0.0], atol=1e-3)
    assert np.abs(twist).max() < 1e-3  # at rest
    np.testing.assert_allclose(world.joint_q(), Q_AWAY, atol=1e-3)  # the fingers stayed away


def test_contact_forces_balance_an_external_push():
    """Held still while pushed up along the pole harder than its weight, the measured contact
    forces on the object must sum to the push reversed plus the weight: friction now has to
    pull the pole down, a check of every contact's tangential sign."""
    sim, hand, obj = SIM, HAND, OBJ  # the push is applied at every physics step
    world = World(sim, hand, ObjectSpec.from_config(obj))
    model = HandModel.from_config(hand, obj, sim.gravity_mps2)
    contacts = Contacts(Posture((Face.LEFT, Face.LEFT, Face.RIGHT)), (-0.21, -0.09, -0.15))
    pose = np.array([0.0, 0.34, 0.0])
    world.reset(pose, model.grasp_q(contacts, pose, press=0.0005))
    hold = Repose(model, contacts, np.zeros(3), 2.0)

    def observe(t):
        p, tw = world.object_state()
        q, qd = world.joint_state()
        return Observation(q, qd, p, tw, t)

    hold.start(observe(0.0))
    weight = obj.mass_kg * sim.gravity_mps2
    push = 1.5 * weight  # along the object's O_z (the pole's long axis)
    for k in range(480):
        pb.applyExternalForce(world.object, 2, [0, 0, push], [0, 0, 0], pb.LINK_FRAME,
                              physicsClientId=world.client)
        world.step(hold.torques(observe(k * world.dt)))
    total = sum(c.normal_force * c.normal + c.tangential_force * c.tangent
                for c in world.contacts())
    theta = world.object_pose()[2]
    axis = np.array([-np.sin(theta), np.cos(theta)])  # O_z in the hand frame
    assert len(world.contacts()) == 3
    assert world.hand_contacts() == []
    np.testing.assert_allclose(total, -push * axis + [0.0, weight], atol=0.02 * weight)
    # the net load is up the pole: each finger's tangential force pulls the pole down
    assert all(c.tangential_force * (c.tangent @ axis) < 0 for c in world.contacts())
    world.close()


def test_control_substeps_hold_the_torque_for_every_physics_step():
    """One step of a world with ``control_substeps=3`` is three physics steps with the same
    torque: the same state, bit for bit, as three steps of a world that updates every step."""
    coarse = World(SimConfig(control_substeps=3), HAND, ObjectSpec.from_config(OBJ))
    fine = World(SimConfig(control_substeps=1), HAND, ObjectSpec.from_config(OBJ))
    try:
        tau = np.array([0.3, -0.2, 0.1, 0.25, -0.3, 0.2])
        for w in (coarse, fine):
            w.reset(FAR, Q_FREE)
        assert coarse.dt == pytest.approx(3 * fine.dt)
        for _ in range(5):
            coarse.step(tau)
            for _ in range(3):
                fine.step(tau)
        np.testing.assert_array_equal(coarse.joint_state()[0], fine.joint_state()[0])
        np.testing.assert_array_equal(coarse.joint_state()[1], fine.joint_state()[1])
        assert coarse.physics_steps == fine.physics_steps == 15
        assert coarse.time_s == pytest.approx(fine.time_s)
    finally:
        coarse.close()
        fine.close()
