"""Which poses the cube's actions reach from its start (paper section IV-D: "any reachable
pose"), on a lattice of object heights and angles.

The cube's actions are reposes, releases and lands (no slides, no whole flips). A state is a
posture (the face of each finger), the finger lifted off the object if any, and a pose cell:

- held by three fingers when some grasp of the posture holds the object there
  (``sample.grasp_of``: reach, joint limits, links and palm clear, a strict squeeze);
- held by two when those two are on different faces, each reaches its face there
  (``sample.face_coords``) and, for some pair of those coordinates, their force distribution
  holds the object still against gravity at that angle (what ``Release`` and ``Land`` ask of
  the pair, ``flip.pair_holds``; adjacent faces included: a bottom tip bearing the weight and a
  side tip pressing).

Edges: a repose to a neighbouring cell (height or angle) held by the same fingers; a release
of a finger whose two partners hold alone; a land of the free finger on any other face where
the three then hold. The search is breadth-first and checks only the cells it visits.

``opposite_only=True`` asks what the action set would reach were only pairs on opposite faces
allowed to carry the object, as for a pole.

It is a diagnostic, not a filter: a cell stands for every pose within half a cell of it, the
object stays at the start's x, and a land may use any coordinate of its new face (the
primitive takes the nearest that holds). A goal is counted as reached when some posture that
reaches its cell holds the object at the goal itself.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from inhand_exp.config import PrimitivesConfig
from inhand_exp.control.flip import OPPOSITE
from inhand_exp.control.grasp import Contacts, Face, Posture
from inhand_exp.control.hand import HandModel
from inhand_exp.control.repose import GraspPlan, object_wrench
from inhand_exp.control.sample import face_coords, grasp_of

State = tuple[Posture, int, int, int]  # posture, lifted finger (-1: none), height and angle cells


@dataclass
class Reach:
    """The states reached from one start, and the checks behind them (cached per state)."""

    model: HandModel
    prim: PrimitivesConfig
    x: float
    zs: np.ndarray
    ts: np.ndarray
    tries: int = 20
    pair_tries: int = 15
    opposite_only: bool = False  # a pair carries the object only from opposite faces
    reached: set[State] = field(default_factory=set)
    _held: dict[State, bool] = field(default_factory=dict)

    @classmethod
    def lattice(cls, model: HandModel, prim: PrimitivesConfig, x: float, z_range, t_range,
                resolution_m: float, resolution_rad: float, **kw) -> Reach:
        """A lattice over heights ``z_range`` and angles ``t_range`` (inclusive, centred)."""
        for name, v in (("resolution_m", resolution_m), ("resolution_rad", resolution_rad)):
            if not v > 0:
                raise ValueError(f"{name} must be > 0, got {v}")

        def axis(lo: float, hi: float, step: float) -> np.ndarray:
            n = int(math.floor((hi - lo) / step + 1e-9))
            return lo + (hi - lo - n * step) / 2 + step * np.arange(n + 1)

        return cls(model, prim, float(x), axis(*z_range, resolution_m),
                   axis(*t_range, resolution_rad), **kw)

    def cell(self, pose: np.ndarray) -> tuple[int, int] | None:
        """The nearest (height, angle) cell, or None outside the lattice by more than half a
        cell."""
        out = []
        for axis, v in ((self.zs, pose[1]), (self.ts, pose[2])):
            i = int(np.argmin(np.abs(axis - v)))
            step = axis[1] - axis[0] if len(axis) > 1 else np.inf
            if abs(axis[i] - v) > step / 2 + 1e-9:
                return None
            out.append(i)
        return out[0], out[1]

    def pose(self, iz: int, it: int) -> np.ndarray:
        return np.array([self.x, self.zs[iz], self.ts[it]])

    def held(self, state: State) -> bool:
        if state not in self._held:
            posture, lifted, iz, it = state
            pose = self.pose(iz, it)
            self._held[state] = (grasp_of(self.model, posture, pose, tries=self.tries) is not None
                                 if lifted < 0 else self._pair_holds(posture, lifted, pose))
        return self._held[state]

    def _pair_holds(self, posture: Posture, lifted: int, pose: np.ndarray) -> bool:
        a, b = (j for j in range(3) if j != lifted)
        if self.opposite_only and posture.faces[a] != OPPOSITE[posture.faces[b]]:
            return False
        if posture.faces[a] == posture.faces[b]:
            return False  # two tips on one face hold nothing still
        if self.model.palm_gap(pose) < self.model.clearance:
            return False
        sets = [face_coords(self.model, j, posture.faces[j], pose, margin=0.1) for j in (a, b)]
        if not all(sets):
            return False
        zero = np.zeros(3)
        _, w_O = object_wrench(self.model, self.prim, pose, zero, (pose, zero, zero))
        rng = np.random.default_rng(0)
        active = tuple(j != lifted for j in range(3))
        for _ in range(self.pair_tries):
            coords = [0.0, 0.0, 0.0]
            coords[a], coords[b] = (float(s[int(rng.integers(len(s)))]) for s in sets)
            plan = GraspPlan.from_contacts(self.model, Contacts(posture, tuple(coords), active),
                                           self.prim)
            if plan.squeeze.solve(w_O) is not None:
                return True
        return False

    def _moves(self, state: State) -> Iterator[State]:
        posture, lifted, iz, it = state
        for jz, jt in ((iz - 1, it), (iz + 1, it), (iz, it - 1), (iz, it + 1)):  # reposes
            if 0 <= jz < len(self.zs) and 0 <= jt < len(self.ts):
                yield posture, lifted, jz, jt
        if lifted < 0:
            for k in range(3):  # releases
                yield posture, k, iz, it
        else:
            for face in Face:  # lands, on another face than the one the finger left
                if face != posture.faces[lifted]:
                    faces = list(posture.faces)
                    faces[lifted] = face
                    yield Posture(tuple(faces)), -1, iz, it

    def search(self, start_pose: np.ndarray, start: Contacts) -> Reach:
        """Every state reached from the start's grasp (breadth-first)."""
        cell = self.cell(start_pose)
        if cell is None:
            raise ValueError(f"the start {np.round(start_pose, 3).tolist()} is outside the lattice")
        first: State = (start.posture, -1, *cell)
        self.reached, frontier = {first}, [first]
        while frontier:
            nxt = []
            for s in frontier:
                for m in self._moves(s):
                    if m not in self.reached and self.held(m):
                        self.reached.add(m)
                        nxt.append(m)
            frontier = nxt
        return self

    def goal_reached(self, xg: np.ndarray) -> bool:
        """Some posture reached, with three fingers, at the goal's cell holds the object at the
        goal itself."""
        cell = self.cell(xg)
        if cell is None:
            return False
        return any(grasp_of(self.model, p, np.asarray(xg, float), tries=self.tries) is not None
                   for p, lifted, jz, jt in self.reached if lifted < 0 and (jz, jt) == cell)

    def angles(self) -> tuple[float, float]:
        """The lowest and highest angle reached with three fingers."""
        held = [self.ts[it] for _, lifted, _, it in self.reached if lifted < 0]
        return float(min(held)), float(max(held))
