"""A free finger's way round the object in joint space, and a tracker that follows it.

A finger that changes sides (a flip) must carry its links round an end of the object. For a
two-link finger rising from the palm that often means changing its elbow branch as well (the
elbow is outside the pole on one side, under the pole's end on the other), and the only way
between the branches is through the straight finger. A path in the object frame tracked by
inverse kinematics of one branch cannot do that; a path in the finger's own two-dimensional
joint space can.

``plan_joint_path`` searches a grid over the joint limits (A*, 8-connected, cells checked
lazily) for joint angles whose links and tip keep a margin of air to the object and stay above
the palm, then shortens the path and checks every segment densely. ``JointPath`` follows
waypoints with one minimum-jerk move per segment and a joint-space PD with feed-forward.
"""

from __future__ import annotations

import heapq
import math

import numpy as np

from inhand_exp.control.clearance import to_object
from inhand_exp.control.hand import HandModel
from inhand_exp.control.repose import min_jerk


class FreeSpace:
    """Which joint angles of ``finger`` keep it clear of the object at ``pose``."""

    def __init__(self, model: HandModel, finger: int, pose: np.ndarray, margin: float,
                 cells: int = 56):
        self.model, self.finger, self.pose, self.margin = model, finger, pose, margin
        f = model.fingers[finger]
        self.lo = np.array(f.q_lower) + 0.05
        self.hi = np.array(f.q_upper) - 0.05
        self.n = cells
        self.step = (self.hi - self.lo) / (cells - 1)
        self._cache: dict[tuple[int, int], bool] = {}
        self._c, self._s = math.cos(pose[2]), math.sin(pose[2])

    def ok(self, q: np.ndarray) -> bool:
        """The links and the tip clear of the object by the margin, joints above the palm."""
        m, i = self.model, self.finger
        if np.any(q < self.lo - 1e-9) or np.any(q > self.hi + 1e-9):
            return False
        if m.finger_gap(i, q, self.pose) < self.margin:
            return False
        tip = m.fingers[i].tip(q)
        x, z = to_object(tip[0], tip[1], self.pose[0], self.pose[1], self._c, self._s)
        hx, hz = m.shape.half_x, m.shape.half_z
        air = math.hypot(max(abs(x) - hx, 0.0), max(abs(z) - hz, 0.0))
        return air >= m.tip_radius + self.margin and tip[1] >= m.fingers[i].base_z + m.tip_radius

    def cell_q(self, cell: tuple[int, int]) -> np.ndarray:
        return self.lo + self.step * np.array(cell)

    def free(self, cell: tuple[int, int]) -> bool:
        hit = self._cache.get(cell)
        if hit is None:
            i, j = cell
            hit = 0 <= i < self.n and 0 <= j < self.n and self.ok(self.cell_q(cell))
            self._cache[cell] = hit
        return hit

    def nearest_free(self, q: np.ndarray) -> tuple[int, int] | None:
        """The free cell nearest ``q`` from which the straight move to ``q`` is clear."""
        base = np.round((q - self.lo) / self.step).astype(int)
        ring = [(0, 0)] + [(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1) if (a, b) != (0, 0)]
        for da, db in sorted(ring, key=lambda d: abs(d[0]) + abs(d[1])):
            cell = (int(base[0] + da), int(base[1] + db))
            if self.free(cell) and self.segment_ok(q, self.cell_q(cell)):
                return cell
        return None

    def segment_ok(self, a: np.ndarray, b: np.ndarray, step_rad: float = 0.02) -> bool:
        n = max(2, int(math.ceil(float(np.max(np.abs(b - a))) / step_rad)) + 1)
        return all(self.ok(a + (b - a) * s) for s in np.linspace(0.0, 1.0, n))


def plan_joint_path(space: FreeSpace, q_start: np.ndarray, q_goal: np.ndarray,
                    max_expand: int = 4000) -> list[np.ndarray] | None:
    """Joint waypoints from ``q_start`` to ``q_goal`` through free space, or None."""
    if space.segment_ok(q_start, q_goal):
        return [q_start, q_goal]
    start, goal = space.nearest_free(q_start), space.nearest_free(q_goal)
    if start is None or goal is None:
        return None
    w = space.step

    def h(c: tuple[int, int]) -> float:
        return math.hypot((c[0] - goal[0]) * w[0], (c[1] - goal[1]) * w[1])

    moves = [(a, b, math.hypot(a * w[0], b * w[1])) for a in (-1, 0, 1) for b in (-1, 0, 1)
             if (a, b) != (0, 0)]
    best = {start: 0.0}
    came: dict[tuple[int, int], tuple[int, int]] = {}
    heap = [(h(start), 0.0, start)]
    expanded = 0
    while heap:
        _, g, cell = heapq.heappop(heap)
        if cell == goal:
            break
        if g > best.get(cell, math.inf):
            continue
        expanded += 1
        if expanded > max_expand:
            return None
        for a, b, cost in moves:
            nxt = (cell[0] + a, cell[1] + b)
            if not space.free(nxt):
                continue
            ng = g + cost
            if ng < best.get(nxt, math.inf):
                best[nxt], came[nxt] = ng, cell
                heapq.heappush(heap, (ng + h(nxt), ng, nxt))
    else:
        return None
    cells = [goal]
    while cells[-1] != start:
        cells.append(came[cells[-1]])
    path = [q_start, *(space.cell_q(c) for c in reversed(cells)), q_goal]
    return _shorten(space, path)


def _shorten(space: FreeSpace, path: list[np.ndarray]) -> list[np.ndarray] | None:
    """Skip every waypoint the straight move past it makes unnecessary; None if a segment of
    the result is not clear."""
    out = [path[0]]
    k = 0
    while k < len(path) - 1:
        j = len(path) - 1
        while j > k + 1 and not space.segment_ok(path[k], path[j]):
            j -= 1
        if not space.segment_ok(path[k], path[j]):
            return None
        out.append(path[j])
        k = j
    return out


def arrival_times(waypoints: list[np.ndarray], t0: float, t1: float) -> list[float]:
    """When each waypoint is reached, moving from ``t0`` to ``t1`` with time in proportion to
    each segment's length in joint space."""
    lengths = [float(np.linalg.norm(b - a)) for a, b in zip(waypoints, waypoints[1:],
                                                            strict=False)]
    total = sum(lengths) or 1.0
    times = [t0]
    for seg in lengths:
        times.append(times[-1] + (t1 - t0) * seg / total)
    return times


class JointPath:
    """Joint-angle target (2,) along waypoints reached at ``times``: one minimum-jerk move per
    segment, tracked by a joint-space PD with feed-forward."""

    def __init__(self, waypoints: list[np.ndarray], times: list[float]):
        if len(times) != len(waypoints):
            raise ValueError("one arrival time per waypoint")
        self.path, self.times = waypoints, times

    def reference(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Joint angles, velocities and accelerations at time ``t``."""
        zero = np.zeros(2)
        if t <= self.times[0]:
            return self.path[0], zero, zero
        for a, b, ta, tb in zip(self.path, self.path[1:], self.times, self.times[1:],
                                strict=False):
            if t <= tb and tb > ta:
                return min_jerk(a, b, tb - ta, t - ta)
        return self.path[-1], zero, zero

    def qdd(self, model: HandModel, finger: int, elbow: int, obs, R: np.ndarray,
            kp: float, kd: float) -> np.ndarray:
        """Joint accelerations (2,) tracking the reference at ``obs.t`` (the object is held
        still, so joint space is fixed to it)."""
        qi, qdi = obs.q[2 * finger:2 * finger + 2], obs.qd[2 * finger:2 * finger + 2]
        q, qd, qdd = self.reference(obs.t)
        return qdd + kp * (q - qi) + kd * (qd - qdi)
