"""The analytic finger model against PyBullet's own multibody algorithms and physical identities.

Each finger of the simulated hand is an independent fixed-base URDF body, so PyBullet's
``calculateMassMatrix``, ``calculateInverseDynamics``, ``calculateJacobian`` and forward
kinematics are an independent reference for ``control.finger.FingerModel``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pybullet as pb
import pytest

from inhand_exp.config import HandConfig, ObjectConfig, SimConfig
from inhand_exp.control.finger import FingerModel
from inhand_exp.control.hand import HandModel
from inhand_exp.sim.world import TIP_LINK, ObjectSpec, World

N_SAMPLES = 20


@pytest.fixture(scope="module")
def world():
    w = World(SimConfig(), HandConfig(), ObjectSpec.from_config(ObjectConfig()))
    yield w
    w.close()


@pytest.fixture(scope="module")
def model() -> HandModel:
    return HandModel.from_config(HandConfig(), ObjectConfig(), SimConfig().gravity_mps2)


def _samples(finger: FingerModel, seed: int):
    """Seeded random (q, qd, qdd) with q inside the joint limits."""
    rng = np.random.default_rng(seed)
    for _ in range(N_SAMPLES):
        q = rng.uniform(finger.q_lower, finger.q_upper)
        yield q, rng.uniform(-5.0, 5.0, 2), rng.uniform(-50.0, 50.0, 2)


def _set_q(world: World, body: int, q: np.ndarray) -> None:
    for j in range(2):
        pb.resetJointState(body, j, float(q[j]), 0.0, physicsClientId=world.client)


@pytest.mark.parametrize("i", range(3))
def test_mass_matrix_matches_pybullet(world, model, i):
    body, finger = world.fingers[i], model.fingers[i]
    for q, _, _ in _samples(finger, 10 + i):
        ref = np.array(pb.calculateMassMatrix(body, list(q), physicsClientId=world.client))
        np.testing.assert_allclose(finger.mass_matrix(q), ref, rtol=0, atol=1e-10)


@pytest.mark.parametrize("i", range(3))
def test_inverse_dynamics_matches_pybullet(world, model, i):
    body, finger = world.fingers[i], model.fingers[i]
    for q, qd, qdd in _samples(finger, 20 + i):
        ref = pb.calculateInverseDynamics(body, list(q), list(qd), list(qdd),
                                          physicsClientId=world.client)
        np.testing.assert_allclose(finger.inverse_dynamics(q, qd, qdd), ref, rtol=0, atol=1e-9)


@pytest.mark.parametrize("i", range(3))
def test_gravity_torque_matches_pybullet(world, model, i):
    """Inverse dynamics at rest is the gravity torque alone."""
    body, finger = world.fingers[i], model.fingers[i]
    for q, _, _ in _samples(finger, 30 + i):
        ref = pb.calculateInverseDynamics(body, list(q), [0.0, 0.0], [0.0, 0.0],
                                          physicsClientId=world.client)
        np.testing.assert_allclose(finger.gravity_torque(q), ref, rtol=0, atol=1e-9)


@pytest.mark.parametrize("i", range(3))
def test_jacobian_and_tip_match_pybullet(world, model, i):
    body, finger = world.fingers[i], model.fingers[i]
    zeros = [0.0, 0.0]
    for q, _, _ in _samples(finger, 40 + i):
        _set_q(world, body, q)
        lin, _ = pb.calculateJacobian(body, TIP_LINK, [0.0, 0.0, 0.0], list(q), zeros, zeros,
                                      physicsClientId=world.client)
        lin = np.array(lin)
        np.testing.assert_allclose(finger.jacobian(q), lin[[0, 2]], rtol=0, atol=1e-9)
        np.testing.assert_allclose(lin[1], 0.0, atol=1e-12)  # planar: no y motion
        pos = pb.getLinkState(body, TIP_LINK, computeForwardKinematics=1,
                              physicsClientId=world.client)[4]
        np.testing.assert_allclose(finger.tip(q), [pos[0], pos[2]], rtol=0, atol=1e-6)
        assert abs(pos[1]) < 1e-12


@pytest.mark.parametrize("i", range(3))
def test_jacobian_is_derivative_of_tip(model, i):
    """J is d(tip)/dq (central differences), independently of PyBullet."""
    finger, h = model.fingers[i], 1e-6
    for q, _, _ in _samples(finger, 50 + i):
        num = np.column_stack([(finger.tip(q + h * e) - finger.tip(q - h * e)) / (2 * h)
                               for e in np.eye(2)])
        np.testing.assert_allclose(finger.jacobian(q), num, rtol=0, atol=1e-8)


@pytest.mark.parametrize("i", range(3))
def test_jacobian_dot_qd_is_finite_difference(model, i):
    finger, h = model.fingers[i], 1e-6
    for q, qd, _ in _samples(finger, 60 + i):
        num = (finger.jacobian(q + qd * h) @ qd - finger.jacobian(q) @ qd) / h
        ref = finger.jacobian_dot_qd(q, qd)
        np.testing.assert_allclose(ref, num, rtol=1e-4, atol=1e-4 * np.abs(qd).max() ** 2)


@pytest.mark.parametrize("i", range(3))
def test_ik_round_trip_both_branches(model, i):
    finger = model.fingers[i]
    reach = finger.l1 + finger.l2
    rng = np.random.default_rng(70 + i)
    solved = {1: 0, -1: 0}
    for _ in range(50):
        # targets in the working half-plane above the base, where both branches fit the limits
        r, phi = rng.uniform(0.05, 0.999) * reach, rng.uniform(0.3, math.pi - 0.3)
        target = np.array([finger.base_x + r * math.cos(phi), finger.base_z + r * math.sin(phi)])
        for elbow in (1, -1):
            q = finger.ik(target, elbow)
            if q is None:
                continue
            solved[elbow] += 1
            assert finger.within_limits(q)
            assert np.sign(q[1]) == elbow
            np.testing.assert_allclose(finger.tip(q), target, rtol=0, atol=1e-12)
    assert min(solved.values()) >= 35  # most targets fit the limits on both branches


@pytest.mark.parametrize("i", range(3))
def test_ik_unreachable_is_none(model, i):
    finger = model.fingers[i]
    reach = finger.l1 + finger.l2
    rng = np.random.default_rng(80 + i)
    for _ in range(20):
        r, phi = rng.uniform(1.001, 3.0) * reach, rng.uniform(-math.pi, math.pi)
        target = np.array([finger.base_x + r * math.cos(phi), finger.base_z + r * math.sin(phi)])
        assert finger.ik(target, 1) is None
        assert finger.ik(target, -1) is None


@pytest.mark.parametrize("i", range(3))
def test_mass_matrix_symmetric_positive_definite(model, i):
    finger = model.fingers[i]
    for q, _, _ in _samples(finger, 90 + i):
        M = finger.mass_matrix(q)
        np.testing.assert_array_equal(M, M.T)
        assert np.linalg.eigvalsh(M).min() > 0


@pytest.mark.parametrize("i", range(3))
def test_inverse_dynamics_is_m_qdd_plus_v_plus_g(model, i):
    finger = model.fingers[i]
    for q, qd, qdd in _samples(finger, 100 + i):
        tau = finger.mass_matrix(q) @ qdd + finger.coriolis(q, qd) + finger.gravity_torque(q)
        np.testing.assert_allclose(finger.inverse_dynamics(q, qd, qdd), tau, rtol=1e-12,
                                   atol=1e-12)


@pytest.mark.parametrize("i", range(3))
def test_coriolis_from_lagrangian(model, i):
    """V = Mdot qd - d/dq (1/2 qd^T M qd) (Lagrange), hence qd^T (Mdot - 2C) qd = 0."""
    finger, h = model.fingers[i], 1e-6
    M = finger.mass_matrix
    for q, qd, _ in _samples(finger, 110 + i):
        m_dot = (M(q + h * qd) - M(q - h * qd)) / (2 * h)
        grad_t = np.array([(qd @ M(q + h * e) @ qd - qd @ M(q - h * e) @ qd) / (4 * h)
                           for e in np.eye(2)])
        V = finger.coriolis(q, qd)
        np.testing.assert_allclose(V, m_dot @ qd - grad_t, rtol=0, atol=1e-7)
        assert abs(qd @ m_dot @ qd - 2 * qd @ V) < 1e-7


@pytest.mark.parametrize("i", range(3))
def test_free_motion_conserves_energy(model, i):
    """Without gravity or torque, M qdd = -V keeps 1/2 qd^T M qd constant (RK4 integration)."""
    finger = dataclasses.replace(model.fingers[i], gravity=0.0)

    def f(x: np.ndarray) -> np.ndarray:
        q, qd = x[:2], x[2:]
        return np.concatenate([qd, np.linalg.solve(finger.mass_matrix(q),
                                                   -finger.coriolis(q, qd))])

    x = np.array([0.3, 1.0, 4.0, -6.0])

    def energy(x: np.ndarray) -> float:
        return 0.5 * x[2:] @ finger.mass_matrix(x[:2]) @ x[2:]

    e0, dt = energy(x), 1e-3
    for _ in range(1000):
        k1 = f(x)
        k2 = f(x + dt / 2 * k1)
        k3 = f(x + dt / 2 * k2)
        k4 = f(x + dt * k3)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    assert abs(x[1] - 1.0) > 0.1  # the elbow actually moved
    assert abs(energy(x) - e0) < 1e-8 * e0
