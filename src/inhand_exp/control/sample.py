"""Seeded sampling of valid grasps: object poses, postures and contacts the hand can hold."""

from __future__ import annotations

import numpy as np

from inhand_exp.control.grasp import Contacts, Face, Posture
from inhand_exp.control.hand import GeometryError, HandModel
from inhand_exp.control.repose import Gains, strict_hold

# Pose ranges of sampled grasps (m, m, rad): centred over the hand, within easy reach.
POSE_LOW = np.array([-0.06, 0.16, -0.4])
POSE_HIGH = np.array([0.06, 0.24, 0.4])


def lone_between(rng: np.random.Generator, half: float, gap: float = 0.06
                 ) -> tuple[Posture, tuple[float, float, float]]:
    """A pole posture with a lone finger between the other two, on the opposite long face."""
    lone = int(rng.integers(3))
    side = Face.TOP if rng.random() < 0.5 else Face.BOTTOM
    other = Face.BOTTOM if side == Face.TOP else Face.TOP
    a = rng.uniform(-half, half - 2 * gap)
    b = rng.uniform(a + 2 * gap, half)
    mid = rng.uniform(a + gap / 2, b - gap / 2)
    pair = sorted((a, b)) if rng.random() < 0.5 else sorted((a, b), reverse=True)
    faces, coords = [other] * 3, [0.0] * 3
    faces[lone], coords[lone] = side, mid
    rest = [i for i in range(3) if i != lone]
    for i, c in zip(rest, pair, strict=True):
        coords[i] = c
    return Posture(tuple(faces)), tuple(coords)


def any_faces(rng: np.random.Generator, half_x: float, half_z: float
              ) -> tuple[Posture, tuple[float, float, float]]:
    """A box posture with every finger on a random face at a random coordinate."""
    faces = tuple(Face(int(f)) for f in rng.integers(4, size=3))
    coords = tuple(float(rng.uniform(-h, h)) for h in
                   (half_x if f in (Face.TOP, Face.BOTTOM) else half_z for f in faces))
    return Posture(faces), coords


def elongated(model: HandModel) -> bool:
    """True for a pole-like object: its grasps use the two long faces only."""
    return model.shape.length_m > 2 * model.shape.width_m


def random_grasp(model: HandModel, rng: np.random.Generator, max_tries: int = 2000,
                 press: float = 0.0005) -> tuple[np.ndarray, Contacts, np.ndarray]:
    """A random object pose and three-finger grasp that the hand reaches and that holds.

    A pole gets a lone finger between the other two on its long faces; a cube any faces.
    Returns ``(pose, contacts, q)``. Rejection sampling, deterministic for a given ``rng``.
    """
    r = model.tip_radius
    half_x, half_z = model.shape.length_m / 2 - 3 * r, model.shape.width_m / 2 - 2 * r
    for _ in range(max_tries):
        pose = rng.uniform(POSE_LOW, POSE_HIGH)
        posture, coords = (lone_between(rng, half_x) if elongated(model)
                           else any_faces(rng, half_x + r, half_z))
        contacts = Contacts(posture, coords)
        if not strict_hold(model, contacts, Gains()):
            continue
        try:
            q = model.grasp_q(contacts, pose, press=press)
        except GeometryError:
            continue
        if all(f.within_limits(q[2 * i:2 * i + 2], margin=0.1)
               for i, f in enumerate(model.fingers)):
            return pose, contacts, q
    raise GeometryError(f"no valid grasp found in {max_tries} tries")
