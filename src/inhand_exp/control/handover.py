"""Pieces shared by the primitives that lift a finger or put one down (flip, release, land).

- ``blended_forces``: contact forces while the load passes between two force plans;
- ``PathTracker``: a free fingertip following a polyline fixed in the object frame;
- ``route_round``: waypoints that carry a tip round a box, outside it, from face to face.
"""

from __future__ import annotations

import numpy as np

from inhand_exp.control.grasp import Face, face_axes
from inhand_exp.control.hand import HandModel
from inhand_exp.control.repose import GraspPlan, contact_force, min_jerk


def blended_forces(mix: list[tuple[GraspPlan, float]], w_O: np.ndarray, R: np.ndarray
                   ) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray]] | None:
    """World forces and inward normals per finger for a weighted blend of plans.

    A blend of feasible solutions is feasible (the cones are convex). Where one plan has no
    solution for this wrench, the others carry the whole load; None if none has one.
    """
    solved = [(p, w, p.squeeze.solve(w_O)) for p, w in mix if w > 0]
    solved = [(p, w, lam) for p, w, lam in solved if lam is not None]
    if not solved:
        return None
    total = sum(w for _, w, _ in solved)
    force = {j: np.zeros(2) for j in range(3)}
    normal: dict[int, np.ndarray] = {}
    for plan, weight, lam in solved:
        for k, j in enumerate(plan.fingers):
            force[j] += weight / total * contact_force(plan, lam, k, R)
            normal[j] = R @ plan.normals_O[k]
    return force, normal


class PathTracker:
    """Tip-centre target along waypoints (object frame) between times ``t0`` and ``t1``.

    Each straight segment is its own minimum-jerk move with time in proportion to its length,
    so the tip stops at every corner instead of cutting it. The finger tracks the target by
    inverse kinematics with a joint-space PD and feed-forward (finite differences of the IK).
    """

    def __init__(self, path: list[np.ndarray], t0: float, t1: float):
        self.path, self.t0, self.t1 = path, t0, t1
        self.lengths = [float(np.linalg.norm(b - a)) for a, b in zip(path, path[1:],
                                                                     strict=False)]

    def target(self, t: float) -> np.ndarray:
        if t <= self.t0:
            return self.path[0]
        total = sum(self.lengths) or 1.0
        elapsed = t - self.t0
        for a, b, seg in zip(self.path, self.path[1:], self.lengths, strict=False):
            span = (self.t1 - self.t0) * seg / total
            if elapsed <= span:
                return min_jerk(a, b, span, elapsed)[0]
            elapsed -= span
        return self.path[-1]

    def dense(self, n: int = 8) -> list[np.ndarray]:
        """Points along the path, to check that all of it is reachable."""
        return [a + (b - a) * s for a, b in zip(self.path, self.path[1:], strict=False)
                for s in np.linspace(0, 1, n)]

    def reachable(self, model: HandModel, finger: int, elbow: int, pose: np.ndarray,
                  R: np.ndarray) -> bool:
        """Every point of the path within reach and limits, with the links clear."""
        f = model.fingers[finger]
        for p in self.dense():
            qi = f.ik(pose[:2] + R @ p, elbow)
            if qi is None or model.finger_gap(finger, qi, pose) < model.clearance:
                return False
        return True

    def qdd(self, model: HandModel, finger: int, elbow: int, obs, R: np.ndarray,
            kp: float, kd: float, h: float = 1e-3) -> np.ndarray:
        """Joint accelerations (2,) tracking the target at ``obs.t``."""
        f = model.fingers[finger]
        qi, qdi = obs.q[2 * finger:2 * finger + 2], obs.qd[2 * finger:2 * finger + 2]
        refs = [f.ik(obs.pose[:2] + R @ self.target(obs.t + k * h), elbow) for k in (0, 1, 2)]
        if any(r is None for r in refs):
            return -kd * qdi
        q0, q1, q2 = refs
        return (q2 - 2 * q1 + q0) / h**2 + kp * (q0 - qi) + kd * ((q1 - q0) / h - qdi)


_RING = (Face.TOP, Face.LEFT, Face.BOTTOM, Face.RIGHT)  # counter-clockwise order


def hover(half_x: float, half_z: float, face: Face, coord: float, gap: float) -> np.ndarray:
    """The point ``gap`` metres off ``face`` at ``coord`` (object frame)."""
    inward, along = face_axes(face)
    depth = half_z if face in (Face.TOP, Face.BOTTOM) else half_x
    return -inward * (depth + gap) + along * coord


def route_round(half_x: float, half_z: float, start: np.ndarray, face_from: Face,
                face_to: Face, end: np.ndarray, gap: float, direction: int | None = None
                ) -> list[np.ndarray]:
    """Waypoints from ``start`` (off ``face_from``) to ``end`` (off ``face_to``), ``gap`` metres
    clear of the box, passing its corners the shorter way round, or counter-clockwise
    (``direction=1``) or clockwise (``-1``) when given."""
    i, j = _RING.index(face_from), _RING.index(face_to)
    if direction is None:
        direction = 1 if (j - i) % 4 <= 2 else -1
    path = [start]
    k = i
    cx, cz = half_x + gap, half_z + gap
    while k != j:
        nxt = (k + direction) % 4
        corner = {frozenset((Face.TOP, Face.LEFT)): (-cx, cz),
                  frozenset((Face.LEFT, Face.BOTTOM)): (-cx, -cz),
                  frozenset((Face.BOTTOM, Face.RIGHT)): (cx, -cz),
                  frozenset((Face.RIGHT, Face.TOP)): (cx, cz)}[frozenset((_RING[k], _RING[nxt]))]
        path.append(np.array(corner))
        k = nxt
    path.append(end)
    return path
