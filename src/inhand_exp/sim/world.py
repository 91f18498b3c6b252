"""The PyBullet world: three planar torque-controlled fingers and a planar object, with accessors.

What collides: every part of the hand that a real hand would bring against the object. The
fingertips, both links of every finger (capsules) and the palm plate (a static box whose top face
is at the finger bases) all collide with the object. The fingers sit at different depths along y,
as a real hand's do, so they pass beside one another and never touch; the palm does not touch
the fingers mounted on it. Nothing of the hand can pass through the object: getting a finger to
the object's other side takes a flip round one of its ends. Only fingertip contacts count as a
grasp (``contacts``, ``grasp_lost``); a link or the palm touching the object is reported by
``hand_contacts``.

The object is a dynamic box on a world-fixed chain (prismatic x, prismatic z, revolute about -y)
whose joint motors are disabled, so it moves only through contact forces and gravity. The
fingers run under TORQUE_CONTROL with their velocity motors disabled. After ``reset`` nothing
sets the state of any body.
"""

from __future__ import annotations

import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from inhand_exp.config import HandConfig, ObjectConfig, PerturbConfig, SimConfig
from inhand_exp.quiet import c_output_silenced
from inhand_exp.sim.urdf import finger_urdf, object_urdf, palm_urdf

with c_output_silenced():  # PyBullet prints its build banner at import, in every process
    import pybullet as pb

class NonFiniteTorque(ValueError):
    """A NaN or infinite torque: a controller fault, never handed to PyBullet."""


TIP_LINK = 2  # link index of the fingertip in each finger
BODY_LINK = 2  # link index of the object body in the object chain


@dataclass(frozen=True)
class ObjectSpec:
    """Geometry and mass of a box-shaped object: long axis ``length_m`` along its local z."""

    length_m: float
    width_m: float
    depth_m: float
    mass_kg: float
    friction: float

    @classmethod
    def from_config(cls, obj: ObjectConfig, perturb: PerturbConfig | None = None) -> ObjectSpec:
        """The object as configured, scaled by ``perturb`` (the simulated object only)."""
        p = perturb or PerturbConfig()
        return cls(obj.length_m * p.length_scale, obj.width_m * p.width_scale, obj.depth_m,
                   obj.mass_kg * p.mass_scale, obj.friction)

    @property
    def inertia(self) -> float:
        """Moment of inertia about the axis normal to the plane through the COM (kg m^2)."""
        return self.mass_kg * (self.length_m**2 + self.width_m**2) / 12

    @property
    def elongated(self) -> bool:
        """A pole, held on its two long sides (the test of ``control.sample.elongated``)."""
        return self.length_m > 2 * self.width_m

    @property
    def hold_cos(self) -> float:
        """Two fingertips hold the object when their inward normals are further apart than
        this cosine: opposite sides for a pole (more than 120 deg, as the paper's "no contact on
        one of the sides" is a drop), and for a cube also two adjacent faces (more than 60
        deg: a bottom tip bearing the weight and a side tip pressing it), which only two tips on
        one face are not."""
        return -0.5 if self.elongated else 0.5


@dataclass(frozen=True)
class Contact:
    """One fingertip-object contact, in the hand frame.

    ``normal`` is the unit normal pointing from the fingertip into the object; ``tangent`` is
    the in-plane unit vector 90 deg counter-clockwise of it. Forces are those the finger exerts
    on the object (N).
    """

    finger: int
    position: np.ndarray
    normal: np.ndarray
    normal_force: float
    tangential_force: float

    @property
    def tangent(self) -> np.ndarray:
        return np.array([-self.normal[1], self.normal[0]])


class World:
    """One PyBullet DIRECT client holding the hand and the object."""

    def __init__(self, sim: SimConfig, hand: HandConfig, obj: ObjectSpec):
        self.substeps = sim.control_substeps
        self.physics_dt = sim.timestep_s
        self.dt = sim.timestep_s * self.substeps  # one ``step``: the control period
        self.max_torque = hand.max_torque_nm
        self.obj = obj
        self._hold_cos = obj.hold_cos  # read by grasp_lost every few steps
        self._cid = pb.connect(pb.DIRECT)
        cid = self._cid
        pb.setGravity(0, 0, -sim.gravity_mps2, physicsClientId=cid)
        pb.setPhysicsEngineParameter(fixedTimeStep=sim.timestep_s,
                                     numSolverIterations=sim.solver_iterations,
                                     numSubSteps=0, deterministicOverlappingPairs=1,
                                     physicsClientId=cid)
        with tempfile.TemporaryDirectory() as tmp:
            self.fingers = [self._load(Path(tmp) / f"finger{i}.urdf", _finger_text(hand),
                                       (x, 0.0, hand.base_z_m))
                            for i, x in enumerate(hand.finger_base_x_m)]
            self.object = self._load(Path(tmp) / "object.urdf", object_urdf(
                obj.length_m, obj.width_m, obj.depth_m, obj.mass_kg), (0.0, 0.0, 0.0))
            xs = hand.finger_base_x_m
            half = (xs[-1] - xs[0]) / 2 + hand.palm_overhang_m
            self.palm = self._load(Path(tmp) / "palm.urdf", palm_urdf(
                half, hand.palm_thickness_m, 4 * obj.depth_m),
                ((xs[0] + xs[-1]) / 2, 0.0, hand.base_z_m))
        self._setup_dynamics(hand, obj)
        self._steps = 0
        self._stamp, self._points_at, self._cache = 0, -1, ()  # see _points
        self.step_wall_s = 0.0  # wall time spent inside stepSimulation (benchmarks)
        self.physics_steps = 0  # stepSimulation calls since the world was made (benchmarks)

    def _load(self, path: Path, text: str, base: tuple[float, float, float]) -> int:
        path.write_text(text)
        return pb.loadURDF(str(path), base, useFixedBase=True,
                           flags=pb.URDF_USE_INERTIA_FROM_FILE, physicsClientId=self._cid)

    def _setup_dynamics(self, hand: HandConfig, obj: ObjectSpec) -> None:
        cid = self._cid
        for body, n in [(self.object, 3)] + [(f, 3) for f in self.fingers]:
            for link in range(-1, n):
                pb.changeDynamics(body, link, linearDamping=0.0, angularDamping=0.0,
                                  jointDamping=0.0, physicsClientId=cid)
        for body in [self.object, *self.fingers]:
            pb.setJointMotorControlArray(body, [0, 1, 2] if body == self.object else [0, 1],
                                         pb.VELOCITY_CONTROL,
                                         forces=[0.0] * (3 if body == self.object else 2),
                                         physicsClientId=cid)
        pb.changeDynamics(self.object, BODY_LINK, lateralFriction=obj.friction,
                          spinningFriction=0.0, rollingFriction=0.0, restitution=0.0,
                          physicsClientId=cid)
        pb.changeDynamics(self.palm, -1, lateralFriction=hand.friction, restitution=0.0,
                          physicsClientId=cid)
        for link in (-1, 0, 1):  # the sliders are not part of the object's shape
            pb.setCollisionFilterPair(self.object, self.palm, link, -1, 0, physicsClientId=cid)
        for f in self.fingers:
            for link in (0, 1, TIP_LINK):
                pb.changeDynamics(f, link, lateralFriction=hand.friction, spinningFriction=0.0,
                                  rollingFriction=0.0, restitution=0.0, physicsClientId=cid)
            for link in range(-1, 3):  # fingers are mounted on the palm
                pb.setCollisionFilterPair(self.palm, f, -1, link, 0, physicsClientId=cid)
            for g in self.fingers:
                if g > f:
                    for a in range(-1, 3):
                        for b in range(-1, 3):
                            pb.setCollisionFilterPair(f, g, a, b, 0, physicsClientId=cid)

    # --- state ------------------------------------------------------------------------------

    def reset(self, pose: np.ndarray, q: np.ndarray) -> None:
        """Place the object at ``pose`` (x, z, theta) and the fingers at ``q`` (6,), at rest."""
        cid = self._cid
        for j in range(3):
            pb.resetJointState(self.object, j, float(pose[j]), 0.0, physicsClientId=cid)
        for i, f in enumerate(self.fingers):
            for j in range(2):
                pb.resetJointState(f, j, float(q[2 * i + j]), 0.0, physicsClientId=cid)
        # contact queries must describe the new state, not the manifold of the last step
        pb.performCollisionDetection(physicsClientId=cid)
        self._steps = 0
        self._stamp += 1  # the contact points describe a new state

    @property
    def time_s(self) -> float:
        """Simulated time since the last reset (s)."""
        return self._steps * self.dt

    def object_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Object pose ``(x, z, theta)`` (m, m, rad) and twist ``(vx, vz, omega)``."""
        states = pb.getJointStates(self.object, (0, 1, 2), physicsClientId=self._cid)
        return (np.array([s[0] for s in states]), np.array([s[1] for s in states]))

    def object_pose(self) -> np.ndarray:
        return self.object_state()[0]

    def object_twist(self) -> np.ndarray:
        return self.object_state()[1]

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint angles ``q`` (6,) (rad) and velocities ``qd`` (6,), finger by finger."""
        cid = self._cid
        states = [s for f in self.fingers for s in pb.getJointStates(f, (0, 1),
                                                                     physicsClientId=cid)]
        return np.array([s[0] for s in states]), np.array([s[1] for s in states])

    def joint_q(self) -> np.ndarray:
        return self.joint_state()[0]

    def joint_qd(self) -> np.ndarray:
        return self.joint_state()[1]

    def tip_positions(self) -> np.ndarray:
        """Fingertip centres (3, 2) in the hand frame (x, z) (m), as simulated."""
        out = np.empty((3, 2))
        for i, f in enumerate(self.fingers):
            p = pb.getLinkState(f, TIP_LINK, computeForwardKinematics=1,
                                physicsClientId=self._cid)[4]
            out[i] = p[0], p[2]
        return out

    def contacts(self) -> list[Contact]:
        """Fingertip-object contacts with the forces the solver applied in the last step.

        PyBullet reports each contact in the order its solver holds the pair, and a query
        filtered by body swaps the ids and the normal but not the friction directions; so the
        unfiltered list is read and each contact is turned to act on the object.
        """
        out = []
        for sign, finger, c in self._tip_points():
            point = c[5] if sign > 0 else c[6]  # the point on the finger
            # contactNormalOnB points from B to A; the forces reported act on A
            normal = sign * np.array([c[7][0], c[7][2]])
            normal /= float(np.hypot(*normal)) or 1.0
            lateral = sign * (c[10] * np.array(c[11]) + c[12] * np.array(c[13]))
            tangent = np.array([-normal[1], normal[0]])
            out.append(Contact(self.fingers.index(finger), np.array([point[0], point[2]]),
                               normal, float(c[9]), float(tangent @ lateral[[0, 2]])))
        return out

    def _tip_points(self):
        """``(sign, finger body, point)`` for each fingertip-object contact point: ``sign`` +1
        when PyBullet lists the object as body A, -1 when it lists it as B."""
        obj = self.object
        for c in self._points():
            if c[1] == obj and c[3] == BODY_LINK and c[2] in self.fingers and c[4] == TIP_LINK:
                yield 1.0, c[2], c
            elif c[2] == obj and c[4] == BODY_LINK and c[1] in self.fingers and c[3] == TIP_LINK:
                yield -1.0, c[1], c

    def _points(self) -> tuple:
        """PyBullet's contact points, queried once per simulated state (``contacts``,
        ``hand_contacts`` and ``grasp_lost`` all read them after a step)."""
        if self._points_at != self._stamp:
            self._cache = pb.getContactPoints(physicsClientId=self._cid)
            self._points_at = self._stamp
        return self._cache

    def hand_contacts(self) -> list[str]:
        """Parts of the hand other than the fingertips touching the object, as names
        (``finger 1 distal``, ``palm``): contacts the controllers did not plan."""
        return sorted({name for name, _ in self.hand_contact_points()})

    def hand_contact_points(self) -> list[tuple[str, np.ndarray]]:
        """Each contact point of ``hand_contacts``: the part's name and where the point lies,
        world ``(x, z)`` (m), what a touch sensor on the links and the palm would report."""
        out = []
        names = {0: "proximal", 1: "distal"}
        for c in self._points():
            if c[1] == self.object:
                b, link_b, at = c[2], c[4], c[5]
            elif c[2] == self.object:
                b, link_b, at = c[1], c[3], c[6]
            else:
                continue
            if b == self.palm:
                out.append(("palm", np.array([at[0], at[2]])))
            elif b in self.fingers and link_b in names:
                out.append((f"finger {self.fingers.index(b)} {names[link_b]}",
                            np.array([at[0], at[2]])))
        return out

    def grasp_lost(self) -> str | None:
        """Why the object is not held, judged from PyBullet's contact points, or None if held.

        Held means at least two fingertips touch the object and two of them push from different
        sides (``ObjectSpec.hold_cos``: opposite sides of a pole, also adjacent faces of a cube).
        A held object that falls all the same is caught by the primitives' course test.
        """
        # plain floats, no Contact objects: this runs every few steps of every primitive
        fingers, normals = set(), []
        for sign, finger, c in self._tip_points():
            nx, nz = sign * c[7][0], sign * c[7][2]
            norm = math.hypot(nx, nz) or 1.0
            fingers.add(finger)
            normals.append((nx / norm, nz / norm))
        if len(fingers) < 2:
            return f"only {len(fingers)} fingertip(s) in contact"
        cos = self._hold_cos
        if not any(ax * bx + az * bz < cos for i, (ax, az) in enumerate(normals)
                   for bx, bz in normals[i + 1:]):
            return "object not held from two sides" if cos > 0 else \
                "object not held from opposite sides"
        return None

    def unstable(self) -> str | None:
        """Why the simulated state is unusable (NaN, runaway velocity), or None if it is fine."""
        return state_problem(*self.object_state(), *self.joint_state())

    # --- stepping ---------------------------------------------------------------------------

    def step(self, tau: np.ndarray) -> None:
        """Apply joint torques ``tau`` (6,) (N m, clipped to the limit) for one control period:
        ``sim.control_substeps`` physics steps (``dt`` seconds). A non-finite torque is refused
        with ``ValueError`` (clipping would turn a NaN into a limit torque unnoticed)."""
        cid, hi = self._cid, self.max_torque
        values = tau.tolist()
        if not all(math.isfinite(v) for v in values):
            raise NonFiniteTorque(f"non-finite joint torque {values}")
        tau = [min(hi, max(-hi, v)) for v in values]
        for _ in range(self.substeps):
            # PyBullet clears a TORQUE_CONTROL torque after each step: set it every step
            for i, f in enumerate(self.fingers):
                pb.setJointMotorControlArray(f, (0, 1), pb.TORQUE_CONTROL,
                                             forces=tau[2 * i:2 * i + 2], physicsClientId=cid)
            t = time.perf_counter()
            pb.stepSimulation(physicsClientId=cid)
            self.step_wall_s += time.perf_counter() - t
        self._steps += 1
        self.physics_steps += self.substeps
        self._stamp += 1

    def close(self) -> None:
        if self._cid is not None and pb.isConnected(self._cid):
            pb.disconnect(self._cid)
        self._cid = None

    def __del__(self) -> None:
        try:  # noqa: SIM105 - contextlib may already be gone at interpreter shutdown
            self.close()
        except Exception:
            pass

    @property
    def client(self) -> int:
        return self._cid


def _finger_text(hand: HandConfig) -> str:
    return finger_urdf(tuple(hand.link_lengths_m), tuple(hand.link_masses_kg),
                       hand.link_radius_m, hand.tip_mass_kg, hand.tip_radius_m,
                       tuple(hand.joint_lower_rad), tuple(hand.joint_upper_rad),
                       hand.max_torque_nm)


def wrap_angle(a: float) -> float:
    """Angle in [-pi, pi)."""
    return (a + math.pi) % (2 * math.pi) - math.pi


def state_problem(pose: np.ndarray, twist: np.ndarray, q: np.ndarray, qd: np.ndarray,
                  max_speed: float = 20.0, max_joint_speed: float = 200.0) -> str | None:
    """Why a simulated state is unusable (NaN, runaway velocity), or None if it is fine.

    Speeds in m/s for the object, rad/s for its rotation and the joints.
    """
    values = (*pose, *twist, *q, *qd)
    if not all(math.isfinite(v) for v in values):
        return "non-finite state"
    if math.hypot(twist[0], twist[1]) > max_speed or abs(twist[2]) > max_joint_speed:
        return f"object velocity ran away ({np.round(twist, 2).tolist()})"
    fastest = max(abs(v) for v in qd)
    if fastest > max_joint_speed:
        return f"joint velocity ran away (max {fastest:.1f} rad/s)"
    return None
