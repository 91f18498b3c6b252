"""Analytic model of one planar two-link finger: kinematics, inverse kinematics and dynamics.

Conventions (the whole project uses them): the hand plane is x-z with z up and gravity along -z;
angles are counter-clockwise seen with x to the right and z up (a rotation about -y). Joint 1
turns the proximal link about the finger base, joint 2 the distal link about the end of link 1;
``q1`` is the proximal link's angle from +x, ``q2`` the distal link's angle relative to link 1.
Units: metres, radians, kilograms, newtons, seconds.

The distal link carries the spherical fingertip (a rigid body of its own in the simulator, joined by
a fixed joint); the model lumps the two into one rigid link, which is exact for a fixed joint.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LinkInertia:
    """Mass (kg), COM distance along the link from its joint (m), inertia about the COM (kg m^2)."""

    mass: float
    com: float
    inertia: float


def rod(mass: float, length: float) -> LinkInertia:
    """A uniform slender rod hinged at one end."""
    return LinkInertia(mass, length / 2, mass * length**2 / 12)


def lump(*parts: tuple[LinkInertia, float]) -> LinkInertia:
    """One rigid link from parts ``(inertia, offset)``, each COM shifted by ``offset`` (m)."""
    mass = sum(p.mass for p, _ in parts)
    com = sum(p.mass * (p.com + off) for p, off in parts) / mass
    inertia = sum(p.inertia + p.mass * (p.com + off - com) ** 2 for p, off in parts)
    return LinkInertia(mass, com, inertia)


@dataclass(frozen=True, slots=True)
class FingerTerms:
    """One finger's state-dependent terms: tip ``(x, z)``, Jacobian ``j``, ``dJ/dt qd`` as
    ``(jdx, jdz)``, mass matrix ``m`` and ``v`` = Coriolis + gravity torques (SI units)."""

    x: float
    z: float
    j11: float
    j12: float
    j21: float
    j22: float
    jdx: float
    jdz: float
    m11: float
    m12: float
    m22: float
    v1: float
    v2: float


@dataclass(frozen=True)
class FingerModel:
    """One finger: base position, link lengths, joint limits and lumped link inertias."""

    base_x: float
    base_z: float
    l1: float
    l2: float
    link1: LinkInertia
    link2: LinkInertia
    q_lower: tuple[float, float]
    q_upper: tuple[float, float]
    gravity: float = 9.81

    @classmethod
    def build(cls, base_x: float, base_z: float, lengths: tuple[float, float],
              masses: tuple[float, float], tip_mass: float, tip_radius: float,
              q_lower: tuple[float, float], q_upper: tuple[float, float],
              gravity: float = 9.81) -> FingerModel:
        """Rods for the links, a solid sphere for the tip at the end of link 2."""
        l1, l2 = lengths
        tip = LinkInertia(tip_mass, 0.0, 0.4 * tip_mass * tip_radius**2)
        link2 = lump((rod(masses[1], l2), 0.0), (tip, l2))
        return cls(base_x, base_z, l1, l2, rod(masses[0], l1), link2,
                   tuple(q_lower), tuple(q_upper), gravity)

    # --- kinematics -------------------------------------------------------------------------

    def tip(self, q: np.ndarray) -> np.ndarray:
        """Fingertip centre in the hand frame, ``W_p_tip`` (m)."""
        q1, q12 = q[0], q[0] + q[1]
        return np.array([self.base_x + self.l1 * math.cos(q1) + self.l2 * math.cos(q12),
                         self.base_z + self.l1 * math.sin(q1) + self.l2 * math.sin(q12)])

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """``J_tip``: d(W_p_tip)/dq, 2x2."""
        q1, q12 = q[0], q[0] + q[1]
        s1, c1, s12, c12 = math.sin(q1), math.cos(q1), math.sin(q12), math.cos(q12)
        return np.array([[-self.l1 * s1 - self.l2 * s12, -self.l2 * s12],
                         [self.l1 * c1 + self.l2 * c12, self.l2 * c12]])

    def jacobian_dot_qd(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """``dJ/dt qd``: the tip acceleration at zero joint acceleration (m/s^2)."""
        q1, q12 = q[0], q[0] + q[1]
        w1, w12 = qd[0], qd[0] + qd[1]
        return np.array([-self.l1 * math.cos(q1) * w1**2 - self.l2 * math.cos(q12) * w12**2,
                         -self.l1 * math.sin(q1) * w1**2 - self.l2 * math.sin(q12) * w12**2])

    def ik(self, target: np.ndarray, elbow: int) -> np.ndarray | None:
        """Joint angles placing the tip centre at ``target``, or None if out of reach/limits.

        ``elbow`` picks the branch: +1 puts the distal link counter-clockwise of the proximal one
        (``q2 > 0``), -1 clockwise.
        """
        dx, dz = target[0] - self.base_x, target[1] - self.base_z
        r2 = dx * dx + dz * dz
        c2 = (r2 - self.l1**2 - self.l2**2) / (2 * self.l1 * self.l2)
        if not -1.0 <= c2 <= 1.0:
            return None
        q2 = elbow * math.acos(c2)
        q1 = math.atan2(dz, dx) - math.atan2(self.l2 * math.sin(q2), self.l1 + self.l2 * c2)
        lo = self.q_lower[0]
        q1 = lo + (q1 - lo) % (2 * math.pi)  # the representative inside the joint's window
        q = np.array([q1, q2])
        return q if self.within_limits(q) else None

    def within_limits(self, q: np.ndarray, margin: float = 0.0) -> bool:
        """True when both joints are inside their limits shrunk by ``margin`` (rad)."""
        return all(lo + margin <= v <= hi - margin
                   for v, lo, hi in zip(q, self.q_lower, self.q_upper, strict=True))

    # --- dynamics ---------------------------------------------------------------------------

    @functools.cached_property
    def _a(self) -> tuple[float, float, float]:
        m1, m2 = self.link1.mass, self.link2.mass
        c1, c2 = self.link1.com, self.link2.com
        a1 = self.link1.inertia + m1 * c1**2 + self.link2.inertia + m2 * (self.l1**2 + c2**2)
        return a1, m2 * self.l1 * c2, self.link2.inertia + m2 * c2**2

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """``M(q)``, 2x2 (kg m^2)."""
        a1, a2, a3 = self._a
        c = a2 * math.cos(q[1])
        return np.array([[a1 + 2 * c, a3 + c], [a3 + c, a3]])

    def coriolis(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """Centrifugal and Coriolis torques ``V(q, qd)`` (N m)."""
        h = self._a[1] * math.sin(q[1])
        return np.array([-h * (2 * qd[0] * qd[1] + qd[1] ** 2), h * qd[0] ** 2])

    def gravity_torque(self, q: np.ndarray) -> np.ndarray:
        """Torques that hold the finger still against gravity (N m)."""
        m1, m2 = self.link1.mass, self.link2.mass
        c1, c12 = math.cos(q[0]), math.cos(q[0] + q[1])
        t2 = m2 * self.link2.com * self.gravity * c12
        return np.array([(m1 * self.link1.com + m2 * self.l1) * self.gravity * c1 + t2, t2])

    def terms(self, q1: float, q2: float, qd1: float, qd2: float) -> FingerTerms:
        """Everything the torque laws need at one state, in plain floats (the hot path).

        Equal to ``tip``, ``jacobian``, ``jacobian_dot_qd``, ``mass_matrix``, ``coriolis`` and
        ``gravity_torque``; computed together so sines and cosines are shared.
        """
        # Python floats: arithmetic on numpy scalars costs several times as much
        q1, q2, qd1, qd2 = float(q1), float(q2), float(qd1), float(qd2)
        c1, s1 = math.cos(q1), math.sin(q1)
        q12 = q1 + q2
        c12, s12 = math.cos(q12), math.sin(q12)
        l1, l2 = self.l1, self.l2
        w12 = qd1 + qd2
        a1, a2, a3 = self._a
        c2a, s2a = a2 * math.cos(q2), a2 * math.sin(q2)
        m1, m2 = self.link1.mass, self.link2.mass
        g2 = m2 * self.link2.com * self.gravity * c12
        return FingerTerms(
            x=self.base_x + l1 * c1 + l2 * c12, z=self.base_z + l1 * s1 + l2 * s12,
            j11=-l1 * s1 - l2 * s12, j12=-l2 * s12, j21=l1 * c1 + l2 * c12, j22=l2 * c12,
            jdx=-l1 * c1 * qd1 * qd1 - l2 * c12 * w12 * w12,
            jdz=-l1 * s1 * qd1 * qd1 - l2 * s12 * w12 * w12,
            m11=a1 + 2 * c2a, m12=a3 + c2a, m22=a3,
            v1=-s2a * (2 * qd1 * qd2 + qd2 * qd2) + (m1 * self.link1.com + m2 * l1)
            * self.gravity * c1 + g2,
            v2=s2a * qd1 * qd1 + g2)

    def inverse_dynamics(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """``tau = M qdd + V + g`` for a free finger (no contact) (N m)."""
        return self.mass_matrix(q) @ qdd + self.coriolis(q, qd) + self.gravity_torque(q)
