"""Seeded sampling of valid grasps: object poses, postures and contacts the hand can hold.

The workspace is a box of object poses (x, z, theta); a pose is kept only with a grasp that the
controllers' model accepts: every tip reaches its contact within the joint limits, every link
and the palm stay clear of the object (``HandModel.grasp_q``) and the contacts admit a squeeze
strictly inside the friction cones (``strict_hold``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from inhand_exp.config import PrimitivesConfig
from inhand_exp.control.grasp import Contacts, Face, Posture, face_axes, rotation
from inhand_exp.control.hand import GeometryError, HandModel, elongated
from inhand_exp.control.repose import strict_hold


@dataclass(frozen=True)
class Workspace:
    """Bounds of the object poses (m, m, rad) that goals and trials are drawn from."""

    low: tuple[float, float, float] = (-0.05, 0.18, -math.pi / 2)
    high: tuple[float, float, float] = (0.05, 0.52, math.pi / 2)

    @classmethod
    def from_config(cls, task) -> Workspace:
        (x0, x1), (z0, z1), (t0, t1) = (task.workspace_x_m, task.workspace_z_m,
                                        task.workspace_theta_rad)
        return cls((x0, z0, t0), (x1, z1, t1))

    def draw(self, rng: np.random.Generator) -> np.ndarray:
        return rng.uniform(self.low, self.high)


def holds_at(model: HandModel, contacts: Contacts, pose: np.ndarray, press: float = 0.0,
             margin: float = 0.05) -> np.ndarray | None:
    """Joint angles holding ``contacts`` at ``pose`` with every joint ``margin`` rad inside its
    limits and every link clear, or None. (Whether the contacts can squeeze is separate:
    ``strict_hold``, which does not depend on the pose.)"""
    try:
        q = model.grasp_q(contacts, pose, press=press)
    except GeometryError:
        return None
    if all(f.within_limits(q[2 * i:2 * i + 2], margin=margin)
           for i, f in enumerate(model.fingers)):
        return q
    return None


GUARD = 1e-9  # a vectorised test this close to its threshold is left to the scalar code


def face_coords(model: HandModel, finger: int, face: Face, pose: np.ndarray,
                step_m: float = 0.005, margin: float = 0.1) -> list[float]:
    """Coordinates along ``face`` (every ``step_m``) where ``finger`` alone can touch the
    object at ``pose``: reach, joint limits with ``margin`` and links clear.

    The grid is checked at once (numpy: inverse kinematics of both elbow branches, limits,
    link gaps, each on the coordinates that passed the test before); a coordinate whose answer
    lies within ``GUARD`` of a threshold, where numpy's rounding could differ from the plain
    floats', is decided by ``_touches``, the scalar reference, so the answer is always the
    reference's."""
    r = model.tip_radius
    n = int((model.shape.half_extent(face) - 2 * r) // step_m)
    f = model.fingers[finger]
    coords = np.arange(-n, n + 1) * step_m
    point, inward = model.shape.local_contact(face, 0.0)
    _, along = face_axes(face)
    ox = point[0] - r * inward[0] + along[0] * coords
    oz = point[1] - r * inward[1] + along[1] * coords
    c, s = math.cos(pose[2]), math.sin(pose[2])
    dx, dz = pose[0] + c * ox - s * oz - f.base_x, pose[1] + s * ox + c * oz - f.base_z
    c2 = (dx * dx + dz * dz - f.l1**2 - f.l2**2) / (2 * f.l1 * f.l2)
    near = np.flatnonzero(np.abs(c2) <= 1.0 + 1e-6)  # reached, or too close to tell
    if not len(near):
        return []
    found, unsure = np.zeros(len(coords), dtype=bool), np.zeros(len(coords), dtype=bool)
    k, q1, q2, inside, doubt = _branches(f, dx, dz, c2, near, margin)
    unsure[k[doubt]] = True
    look = np.flatnonzero(inside & ~doubt)
    if len(look):
        q1, q2, k = q1[look], q2[look], k[look]
        gap = model.joint_gaps(finger, q1, q2, pose)
        doubt = np.abs(gap - model.clearance) < GUARD
        ex, ez, tx, tz = model.elbow_tip(finger, q1, q2)
        for x, z in ((ex, ez), (tx, tz)):  # joint_gaps' "below the palm" test: elbow and tip
            doubt |= (np.abs(z - f.base_z) < GUARD) | (np.abs(x - model.palm_x[0]) < GUARD) | (
                np.abs(x - model.palm_x[1]) < GUARD)
        found[k[(gap >= model.clearance) & ~doubt]] = True
        unsure[k[doubt]] = True
    for j in np.flatnonzero(unsure & ~found):
        found[j] = _touches(model, finger, face, pose, float(coords[j]), margin)
    return [float(v) for v in coords[found]]


def _branches(f, dx: np.ndarray, dz: np.ndarray, c2: np.ndarray, near: np.ndarray,
              margin: float) -> tuple[np.ndarray, ...]:
    """``FingerModel.ik`` of both elbow branches for the targets ``near`` (tip offsets
    ``dx, dz`` from the base, ``c2`` the cosine of the elbow angle): the coordinate index of
    each row, its joint angles, whether they reach inside the limits less ``margin``, and
    whether a test came within ``GUARD`` of its threshold. The first half is elbow +1
    (q2 > 0), as ``ik``."""
    k = np.concatenate([near, near])
    elbow = np.repeat([1.0, -1.0], len(near))
    cc = c2[k]
    doubt = np.abs(np.abs(cc) - 1.0) < 1e-6  # acos is steep there: a wide band
    q2 = elbow * np.arccos(np.clip(cc, -1.0, 1.0))
    q1 = np.arctan2(dz[k], dx[k]) - np.arctan2(f.l2 * np.sin(q2), f.l1 + f.l2 * cc)
    wrapped = np.mod(q1 - f.q_lower[0], 2 * math.pi)
    doubt |= (wrapped < GUARD) | (wrapped > 2 * math.pi - GUARD)
    q1 = f.q_lower[0] + wrapped
    inside = np.abs(cc) <= 1.0
    for q, a, b in ((q1, f.q_lower[0], f.q_upper[0]), (q2, f.q_lower[1], f.q_upper[1])):
        for lo_q, hi_q in ((a, b), (a + margin, b - margin)):  # ik's own test, then margin's
            inside &= (lo_q <= q) & (q <= hi_q)
            doubt |= (np.abs(q - lo_q) < GUARD) | (np.abs(q - hi_q) < GUARD)
    return k, q1, q2, inside, doubt


def _touches(model: HandModel, finger: int, face: Face, pose: np.ndarray, coord: float,
             margin: float) -> bool:
    """``face_coords``' test of one coordinate, in plain floats (the reference)."""
    r = model.tip_radius
    f = model.fingers[finger]
    point, inward = model.shape.local_contact(face, coord)
    target = pose[:2] + rotation(pose[2]) @ (point - r * inward)
    for elbow in (1, -1):
        qi = f.ik(target, elbow)
        if (qi is not None and f.within_limits(qi, margin)
                and model.finger_gap(finger, qi, pose) >= model.clearance):
            return True
    return False


def lone_finger(posture: Posture) -> int:
    """The finger alone on its face in a pole's posture (two fingers share the other face)."""
    faces = posture.faces
    return next(i for i in range(3) if faces.count(faces[i]) == 1)


def grasp_of(model: HandModel, posture: Posture, pose: np.ndarray,
             rng: np.random.Generator | None = None, tries: int = 60,
             margin: float = 0.1, lone_min: float | None = None) -> Contacts | None:
    """Contacts of ``posture`` that hold the object at ``pose`` (``holds_at`` and
    ``strict_hold``), or None when none is found; with ``lone_min``, only grasps whose lone
    finger (a pole's finger alone on its face) is at that coordinate or above.

    Each finger's reachable coordinates are found on a 5 mm grid first; then up to ``tries``
    triples of them are checked: random ones with ``rng``; without it (a deterministic
    existence check), first the widest pair with the lone finger nearest its middle, then
    seeded random ones. For a pole whose posture has a lone finger on one side, only triples
    with the lone finger between the other two are tried: no other three-point grasp squeezes.
    """
    if model.palm_gap(pose) < model.clearance:
        return None
    sets = []
    for i, face in enumerate(posture.faces):  # a finger that reaches nowhere ends the search
        sets.append(face_coords(model, i, face, pose, margin=margin))
        if not sets[-1]:
            return None
    faces = posture.faces
    lone = [i for i in range(3) if faces.count(faces[i]) == 1]
    if lone_min is not None and lone:
        sets[lone[0]] = [v for v in sets[lone[0]] if v >= lone_min]
        if not sets[lone[0]]:
            return None
    gen = rng if rng is not None else np.random.default_rng(0)
    cands: list[tuple[float, float, float]] = []
    if elongated(model) and lone:
        k = lone[0]
        a, b = (j for j in range(3) if j != k)
        if rng is None:  # the widest pairs first, the lone finger nearest their middle
            for lo, hi in ((a, b), (b, a)):
                c = [0.0, 0.0, 0.0]
                c[lo], c[hi] = min(sets[lo]), max(sets[hi])
                c[k] = min(sets[k], key=lambda v, m=(c[lo] + c[hi]) / 2: abs(v - m))
                cands.append((c[0], c[1], c[2]))
    for _ in range(40 * tries):
        if len(cands) >= tries:
            break
        c = tuple(float(s[int(gen.integers(len(s)))]) for s in sets)
        if elongated(model) and lone:
            k = lone[0]
            a, b = (c[j] for j in range(3) if j != k)
            if not min(a, b) < c[k] < max(a, b):
                continue
        cands.append(c)
    gains = PrimitivesConfig()
    for c in cands:
        contacts = Contacts(posture, c)
        if strict_hold(model, contacts, gains) and holds_at(model, contacts, pose,
                                                            margin=margin) is not None:
            return contacts
    return None


def postures(model: HandModel) -> list[Posture]:
    """The grasp postures of the object: a pole's lone-finger postures on its long sides."""
    if elongated(model):
        sides = (Face.LEFT, Face.RIGHT)
        return [Posture((a, b, c)) for a in sides for b in sides for c in sides
                if len({a, b, c}) == 2]
    return [Posture((a, b, c)) for a in Face for b in Face for c in Face]


def random_grasp(model: HandModel, rng: np.random.Generator,
                 workspace: Workspace | None = None, max_tries: int = 2000,
                 press: float = 0.0005, posture: Posture | None = None,
                 exclude: Posture | None = None) -> tuple[np.ndarray, Contacts, np.ndarray]:
    """A pose drawn uniformly from the part of ``workspace`` the hand can hold, and a
    three-finger grasp that holds it: the tips reach, the links are clear, the contacts squeeze.

    Each pose drawn from the box is kept when some posture (``posture`` if given, never
    ``exclude``; tried in random order) has a grasp there, so every holdable pose is as likely
    as any other, however few postures hold it. Returns ``(pose, contacts, q)``; deterministic
    for a given ``rng``.
    """
    ws = workspace or Workspace()
    choices = [posture] if posture is not None else [p for p in postures(model) if p != exclude]
    for _ in range(max_tries):
        pose = ws.draw(rng)
        if model.palm_gap(pose) < model.clearance:
            continue
        for k in rng.permutation(len(choices)):
            contacts = grasp_of(model, choices[int(k)], pose, rng, tries=8)
            if contacts is not None:
                q = holds_at(model, contacts, pose, press=press, margin=0.1)
                if q is not None:
                    return pose, contacts, q
    raise GeometryError(f"no valid grasp found in {max_tries} tries")


def pinch_grasp(model: HandModel, rng: np.random.Generator, finger: int,
                workspace: Workspace | None = None, max_tries: int = 4000,
                press: float = 0.0005) -> tuple[np.ndarray, Contacts, np.ndarray]:
    """A random pole grasp in which the two fingers other than ``finger`` pinch the object from
    opposite sides at nearly the same place (within 1 cm), so that they could hold it alone:
    the start of a flip or a release of ``finger``. Returns ``(pose, contacts, q)``."""
    ws = workspace or Workspace()
    a, b = (j for j in range(3) if j != finger)
    gains = PrimitivesConfig()
    for _ in range(max_tries):
        pose = ws.draw(rng)
        faces = [Face.LEFT, Face.LEFT, Face.LEFT]
        faces[a] = Face.LEFT if rng.random() < 0.5 else Face.RIGHT
        faces[b] = Face.RIGHT if faces[a] == Face.LEFT else Face.LEFT
        faces[finger] = Face.LEFT if rng.random() < 0.5 else Face.RIGHT
        posture = Posture(tuple(faces))
        sets = [face_coords(model, i, f, pose) for i, f in enumerate(faces)]
        if not all(sets):
            continue
        coords = [float(s[int(rng.integers(len(s)))]) for s in sets]
        coords[b] = coords[a] + float(rng.uniform(-0.01, 0.01))
        contacts = Contacts(posture, tuple(coords))
        q = holds_at(model, contacts, pose, press=press, margin=0.1)
        if q is not None and strict_hold(model, contacts, gains):
            return pose, contacts, q
    raise GeometryError(f"no pinch grasp for finger {finger} found in {max_tries} tries")
