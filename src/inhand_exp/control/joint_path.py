"""A free finger's way round the object in joint space, and a tracker that follows it.

A finger that changes sides (a flip) must carry its links round an end of the object. For a
two-link finger rising from the palm that often means changing its elbow branch as well (the
elbow is outside the pole on one side, under the pole's end on the other), and the only way
between the branches is through the straight finger. A path in the object frame tracked by
inverse kinematics of one branch cannot do that; a path in the finger's own two-dimensional
joint space can.

``plan_joint_path`` searches a grid over the joint limits (Dijkstra, 8-connected) for joint
angles whose links and tip keep a margin of air to the object and stay above
the palm, then shortens the path and checks every segment densely; when that check fails, it
searches again on a grid twice as fine. ``JointPath`` follows
waypoints with one minimum-jerk move per segment and a joint-space PD with feed-forward.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy import ndimage
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from inhand_exp.control.clearance import to_object
from inhand_exp.control.hand import HandModel
from inhand_exp.control.repose import min_jerk

SCALAR_POINTS = 8  # segments checked at fewer points than this are checked point by point
STEP_RAD = 0.02  # a segment is checked at points at most this far apart in joint space
FINEST_CELLS = 112  # the finest grid a path is searched on (cells per joint)


def segment_points(a: np.ndarray, b: np.ndarray, step_rad: float = STEP_RAD) -> np.ndarray:
    """Joint angles (n, 2) from ``a`` to ``b``, both included, at most ``step_rad`` apart."""
    n = max(2, int(math.ceil(float(np.max(np.abs(b - a))) / step_rad)) + 1)
    return a + (b - a) * np.linspace(0.0, 1.0, n)[:, None]


class FreeSpace:
    """Which joint angles of ``finger`` keep it clear of the object at ``pose``.

    The grid of ``cells`` x ``cells`` joint angles over the limits is checked at once (numpy),
    and the shortest ways through its free cells from a start cell are found once (Dijkstra,
    8-connected, ``scipy.sparse.csgraph``) for every goal a flip tries.
    """

    def __init__(self, model: HandModel, finger: int, pose: np.ndarray, margin: float,
                 cells: int = 56):
        self.model, self.finger, self.pose, self.margin = model, finger, pose, margin
        f = model.fingers[finger]
        self.lo = np.array(f.q_lower) + 0.05
        self.hi = np.array(f.q_upper) - 0.05
        self.n = cells
        self.step = (self.hi - self.lo) / (cells - 1)
        self._c, self._s = math.cos(pose[2]), math.sin(pose[2])
        self._graph = None
        self._ways: dict[tuple[int, int], np.ndarray] = {}  # start cell -> predecessors
        self._nearest: dict[bytes, tuple[int, int] | None] = {}  # joint angles -> free cell

    @functools.cached_property
    def grid(self) -> np.ndarray:
        """Which cells (``cells`` x ``cells``, first joint by row) are free: computed when a
        path is first searched for (many flips are refused before), each proximal link once."""
        k = np.arange(self.n)
        return self._ok((self.lo[0] + self.step[0] * k)[:, None],
                        (self.lo[1] + self.step[1] * k)[None, :])

    @functools.cached_property
    def components(self) -> np.ndarray:
        """The connected pieces of the free cells (8-connected, the moves of the search): a
        label per cell, 0 where it is blocked. A chain of cells joins two free cells exactly
        when they carry one label."""
        labels, _ = ndimage.label(self.grid, structure=np.ones((3, 3), dtype=int))
        return labels

    def component(self, q: np.ndarray) -> int:
        """The label of the free cell a search from or to ``q`` uses (``nearest_free``), 0
        when there is none."""
        cell = self.nearest_free(q)
        return 0 if cell is None else int(self.components[cell])

    def ok_many(self, Q: np.ndarray) -> np.ndarray:
        """For each row of ``Q`` (n, 2): the links and the tip clear of the object by the
        margin, joints inside the limits and above the palm."""
        return self._ok(Q[:, 0], Q[:, 1])

    def _ok(self, q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
        """``ok_many`` for first and second joint angles that broadcast together."""
        m, i = self.model, self.finger
        f = m.fingers[i]
        inside = ((self.lo[0] - 1e-9 <= q1) & (self.hi[0] + 1e-9 >= q1)
                  & (self.lo[1] - 1e-9 <= q2) & (self.hi[1] + 1e-9 >= q2))
        q12 = q1 + q2
        tx = f.base_x + f.l1 * np.cos(q1) + f.l2 * np.cos(q12)
        tz = f.base_z + f.l1 * np.sin(q1) + f.l2 * np.sin(q12)
        x, z = to_object(tx, tz, self.pose[0], self.pose[1], self._c, self._s)
        hx, hz = m.shape.half_x, m.shape.half_z
        air = np.hypot(np.maximum(np.abs(x) - hx, 0.0), np.maximum(np.abs(z) - hz, 0.0))
        return (inside & (m.joint_gaps(i, q1, q2, self.pose) >= self.margin)
                & (air >= m.tip_radius + self.margin) & (tz >= f.base_z + m.tip_radius))

    def ok(self, q: np.ndarray) -> bool:
        """``ok_many`` for one joint vector (plain floats: cheaper than numpy for one)."""
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

    @functools.cached_property
    def finer(self) -> FreeSpace:
        """The same free space on a grid of twice as many cells per joint."""
        return FreeSpace(self.model, self.finger, self.pose, self.margin, cells=2 * self.n)

    def cell_q(self, cell: tuple[int, int]) -> np.ndarray:
        return self.lo + self.step * np.array(cell)

    def free(self, cell: tuple[int, int]) -> bool:
        i, j = cell
        return bool(0 <= i < self.n and 0 <= j < self.n and self.grid[i, j])

    def nearest_free(self, q: np.ndarray) -> tuple[int, int] | None:
        """The free cell nearest ``q`` from which the straight move to ``q`` is clear (found
        once per ``q``: a flip searches from one start to several goals)."""
        key = np.asarray(q, float).tobytes()
        if key not in self._nearest:
            self._nearest[key] = self._nearest_free(q)
        return self._nearest[key]

    def _nearest_free(self, q: np.ndarray) -> tuple[int, int] | None:
        base = np.round((q - self.lo) / self.step).astype(int)
        ring = [(0, 0)] + [(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1) if (a, b) != (0, 0)]
        for da, db in sorted(ring, key=lambda d: abs(d[0]) + abs(d[1])):
            cell = (int(base[0] + da), int(base[1] + db))
            if self.free(cell) and self.segment_ok(q, self.cell_q(cell)):
                return cell
        return None

    def segment_ok(self, a: np.ndarray, b: np.ndarray) -> bool:
        points = segment_points(a, b)
        if len(points) <= SCALAR_POINTS:
            return all(self.ok(q) for q in points)
        return bool(self.ok_many(points).all())

    def cells_between(self, start: tuple[int, int], goal: tuple[int, int]
                      ) -> list[tuple[int, int]] | None:
        """The shortest chain of free cells from ``start`` to ``goal`` (both included)."""
        if start not in self._ways:
            _, pred = dijkstra(self._free_graph(), indices=start[0] * self.n + start[1],
                               return_predecessors=True)
            self._ways[start] = pred
        pred = self._ways[start]
        k, first = goal[0] * self.n + goal[1], start[0] * self.n + start[1]
        if k != first and pred[k] < 0:
            return None
        chain = [k]
        while chain[-1] != first:
            chain.append(int(pred[chain[-1]]))
        return [divmod(c, self.n) for c in reversed(chain)]

    def _free_graph(self) -> csr_matrix:
        """Edges between 8-neighbouring free cells, weighted by their distance in joint space."""
        if self._graph is None:
            n, free = self.n, self.grid
            rows, cols, cost = [], [], []
            idx = np.arange(n * n).reshape(n, n)
            for a in (-1, 0, 1):
                for b in (-1, 0, 1):
                    if (a, b) == (0, 0):
                        continue
                    src = (slice(max(0, -a), n - max(0, a)), slice(max(0, -b), n - max(0, b)))
                    dst = (slice(max(0, a), n - max(0, -a)), slice(max(0, b), n - max(0, -b)))
                    both = free[src] & free[dst]
                    rows.append(idx[src][both])
                    cols.append(idx[dst][both])
                    cost.append(np.full(int(both.sum()),
                                        math.hypot(a * self.step[0], b * self.step[1])))
            self._graph = csr_matrix((np.concatenate(cost),
                                      (np.concatenate(rows), np.concatenate(cols))),
                                     shape=(n * n, n * n))
        return self._graph


def plan_joint_path(space: FreeSpace, q_start: np.ndarray, q_goal: np.ndarray
                    ) -> list[np.ndarray] | None:
    """Joint waypoints from ``q_start`` to ``q_goal`` through free space, or None.

    A chain of free cells can still fail the dense check of its segments: between two free
    cell centres a straight run may cut the corner of the object. The search is then made
    again on the grid of twice the resolution (``FreeSpace.finer``), built only for this.
    """
    if space.segment_ok(q_start, q_goal):
        return [q_start, q_goal]
    while True:
        cells = _chain(space, q_start, q_goal)
        if cells is None:
            return None
        path = _shorten(space, [q_start, *(space.cell_q(c) for c in _corners(cells)), q_goal])
        if path is not None or space.n >= FINEST_CELLS:
            return path
        space = space.finer


def _chain(space: FreeSpace, q_start: np.ndarray, q_goal: np.ndarray
           ) -> list[tuple[int, int]] | None:
    """The free cells from the one nearest ``q_start`` to the one nearest ``q_goal``."""
    start, goal = space.nearest_free(q_start), space.nearest_free(q_goal)
    if start is None or goal is None:
        return None
    return space.cells_between(start, goal)


def _corners(cells: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """The cells of a chain where it turns (and its ends): the straight runs between them are
    the same segments in joint space."""
    out = [cells[0]]
    for a, b, c in zip(cells, cells[1:], cells[2:], strict=False):
        if (b[0] - a[0], b[1] - a[1]) != (c[0] - b[0], c[1] - b[1]):
            out.append(b)
    if len(cells) > 1:
        out.append(cells[-1])
    return out


def _shorten(space: FreeSpace, path: list[np.ndarray]) -> list[np.ndarray] | None:
    """Skip every waypoint the straight move past it makes unnecessary; None if a segment of
    the result is not clear. The moves from one waypoint to all later ones are checked in one
    batch (at the points ``FreeSpace.segment_ok`` checks)."""
    out = [path[0]]
    k = 0
    while k < len(path) - 1:
        points, owner = _segments(path[k], np.array(path[k + 1:]))
        blocked = np.zeros(len(path) - k - 1, dtype=bool)
        blocked[owner[~space.ok_many(points)]] = True
        clear = np.flatnonzero(~blocked)
        if not len(clear):
            return None
        k += 1 + int(clear[-1])
        out.append(path[k])
    return out


def _segments(a: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``segment_points(a, b)`` for every row ``b`` of ``ends``, concatenated, and the row
    each point belongs to (the same points, computed at once)."""
    span = np.max(np.abs(ends - a), axis=1)
    counts = np.maximum(2, np.ceil(span / STEP_RAD).astype(int) + 1)
    owner = np.repeat(np.arange(len(ends)), counts)
    starts = np.cumsum(counts) - counts
    t = (np.arange(len(owner)) - starts[owner]) * np.repeat(1.0 / (counts - 1), counts)
    t[starts + counts - 1] = 1.0  # as numpy's linspace ends: exactly at b
    return a + (ends[owner] - a) * t[:, None], owner


def arrival_times(waypoints: list[np.ndarray], t0: float, t1: float,
                  power: float = 1.0) -> list[float]:
    """When each waypoint is reached, moving from ``t0`` to ``t1`` with time in proportion to
    each segment's length in joint space (to its square root with ``power=0.5``: every
    segment then asks for the same peak acceleration, where in proportion to the length a
    short segment beside a long one is crossed in a jerk the joints cannot follow)."""
    lengths = [float(np.linalg.norm(b - a)) ** power for a, b in zip(waypoints, waypoints[1:],
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
