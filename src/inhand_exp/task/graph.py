"""The graph of the search baseline (paper section IV-A, after Cruciani et al. 2019).

Nodes are the cells of (posture, three contact coordinates, object pose) that the hand holds:
object poses on a lattice of ``resolution_m`` in x and z and ``resolution_rad`` in angle over the
task's workspace, contact coordinates on a lattice of ``contact_resolution_m`` along the pole's
long faces, and every posture (which face each finger is on). A cell is a node when, by the
controllers' own model, every finger reaches its contact within its joint limits with its links
clear of the object and the palm, the object clears the palm, and the three contacts can squeeze
it inside the friction cones with the slack the primitives ask of a grasp they move or end in
(``sample.face_coords`` per finger, ``repose.strict_hold`` with ``firm``).

Edges join neighbouring nodes by one primitive:

- repose: the same contacts, the pose one cell away along x, z or the angle;
- slide: one finger's coordinate one cell away, the rest unchanged, in the directions the slide's
  own force check allows at both ends of the edge (``slide_table``; the lone finger of a pole
  cannot slide down it near upright, for instance);
- flip (finger 0, "flip left", and finger 2, "flip right"): that finger to the other face at any
  coordinate, the pose and the other two contacts unchanged, allowed only when the two staying
  fingers are on opposite faces and can hold the object alone against gravity at the cell's
  angle (the force distribution the flip itself needs, ``flip.pair_holds``: two contacts
  barely more than a pole's width apart along it can, others cannot), and when the finger's
  joint space has a way from its lift off the old face to its hover over the new one
  (``way_table``: for an upright pole, only when it is held high enough for the finger to pass
  under its lower end). Each direction is checked on its own.

An edge weighs the simulated time of the mid-level actions that carry it out (a 2 cm cell is
two 1 cm reposes of ``primitives.repose_duration_s``). Every check is per finger and per cell,
so the whole lattice is checked as a few numpy tables; the graph is a directed sparse matrix
over the nodes alone.
"""

from __future__ import annotations

import functools
import hashlib
import itertools
import json
import math
import os
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf
from scipy import sparse
from scipy.sparse import csgraph

from inhand_exp.config import (
    ConfigError,
    HandConfig,
    ObjectConfig,
    PrimitivesConfig,
    SearchConfig,
    TaskConfig,
    typed,
)
from inhand_exp.control.flip import AIR_M, LIFT_M, PRESS_M, ik_clear
from inhand_exp.control.forces import Squeeze
from inhand_exp.control.grasp import (
    Contacts,
    Face,
    Posture,
    contact_frames,
    grasp_matrix,
    rotation,
)
from inhand_exp.control.hand import HandModel
from inhand_exp.control.handover import hover
from inhand_exp.control.joint_path import FreeSpace
from inhand_exp.control.repose import GraspPlan, object_wrench, strict_hold
from inhand_exp.control.sample import Workspace, postures
from inhand_exp.control.slide import MAX_PUSH_N, drag_of, slide_forces
from inhand_exp.task.goals import FLIP_FINGERS

SIDES = (Face.LEFT, Face.RIGHT)
FIELDS_KEPT = 64  # goal cells whose distances a graph keeps (``PoseGraph.to_goal``)
GRAPH_VERSION = 5  # bump when the graph's definition changes: old caches are not reused


@dataclass(frozen=True)
class Lattice:
    """The cell centres: x, z (m), angle (rad) and contact coordinate (m)."""

    xs: np.ndarray
    zs: np.ndarray
    ts: np.ndarray
    cs: np.ndarray

    @classmethod
    def build(cls, model: HandModel, workspace: Workspace, resolution_m: float,
              resolution_rad: float, contact_resolution_m: float) -> Lattice:
        for name, v in (("resolution_m", resolution_m), ("resolution_rad", resolution_rad),
                        ("contact_resolution_m", contact_resolution_m)):
            if not v > 0:
                raise ValueError(f"{name} must be > 0, got {v}")

        def axis(lo: float, hi: float, step: float) -> np.ndarray:
            n = int(math.floor((hi - lo) / step + 1e-9))
            return lo + (hi - lo - n * step) / 2 + step * np.arange(n + 1)  # centred

        (x0, z0, t0), (x1, z1, t1) = workspace.low, workspace.high
        reach = model.shape.half_z - 2 * model.tip_radius  # a tip stays on the face
        n = int(reach // contact_resolution_m)
        return cls(axis(x0, x1, resolution_m), axis(z0, z1, resolution_m),
                   axis(t0, t1, resolution_rad), contact_resolution_m * np.arange(-n, n + 1))

    @property
    def shape(self) -> tuple[int, int, int, int]:
        return len(self.cs), len(self.xs), len(self.zs), len(self.ts)

    def pose_cell(self, pose: np.ndarray) -> tuple[int, int, int] | None:
        """The nearest pose cell, or None outside the lattice by more than half a cell."""
        out = []
        for axis, v in zip((self.xs, self.zs, self.ts), pose, strict=True):
            i = int(np.argmin(np.abs(axis - v)))
            step = axis[1] - axis[0] if len(axis) > 1 else np.inf
            if abs(axis[i] - v) > step / 2 + 1e-9:
                return None
            out.append(i)
        return tuple(out)

    def contact_cell(self, c: float, reach: float = 0.0) -> int | None:
        """The nearest contact cell, or None further than half a cell from the lattice; the
        end cells also take the ends of the face, up to ``reach`` from its centre (the lattice
        stops a whole cell short of them when the reach is not a whole number of cells)."""
        i = int(np.argmin(np.abs(self.cs - c)))
        step = self.cs[1] - self.cs[0] if len(self.cs) > 1 else np.inf
        if abs(self.cs[i] - c) <= step / 2 + 1e-9 or abs(c) <= reach:
            return i
        return None


def pair_table(model: HandModel, lattice: Lattice, posture: Posture, finger: int,
               prim: PrimitivesConfig) -> np.ndarray:
    """``H[k, k', t]``: with ``finger`` lifted, the other two fingers of ``posture`` at
    coordinates ``cs[k]`` and ``cs[k']`` (in finger order) hold the object still at angle
    ``ts[t]``: their force distribution balances its weight inside the friction cones, with the
    normal forces of ``prim``."""
    K, T = len(lattice.cs), len(lattice.ts)
    stay = [j for j in range(3) if j != finger]
    zero = np.zeros(3)
    wrenches = []  # what the contacts apply to hold the object still, per angle (object frame)
    for t in lattice.ts:
        pose = np.array([0.0, 0.0, float(t)])
        wrenches.append(object_wrench(model, prim, pose, zero, (pose, zero, zero))[1])
    H = np.zeros((K, K, T), dtype=bool)
    for k, k2 in itertools.product(range(K), repeat=2):
        coords = [0.0, 0.0, 0.0]
        coords[stay[0]], coords[stay[1]] = float(lattice.cs[k]), float(lattice.cs[k2])
        active = tuple(j != finger for j in range(3))
        pts, nrm = contact_frames(model.shape, Contacts(posture, tuple(coords), active),
                                  np.zeros(3))
        squeeze = Squeeze.build(grasp_matrix(pts[stay], nrm[stay]),
                                model.mu * prim.friction_margin, prim.min_normal_force_n,
                                prim.max_normal_force_n)
        for t, w in enumerate(wrenches):
            H[k, k2, t] = squeeze.solve(w) is not None
    return H


SLIDE_SIGNS = (1, -1)  # the first axis of ``slide_table``: up, then down the coordinate


def slide_table(model: HandModel, lattice: Lattice, posture: Posture, finger: int,
                prim: PrimitivesConfig, holds: np.ndarray,
                max_push_n: float = MAX_PUSH_N) -> np.ndarray:
    """``S[d, k0, k1, k2, t]``: at contacts ``cs[k0], cs[k1], cs[k2]`` of ``posture`` and angle
    ``ts[t]``, ``finger`` can slide along its face in the direction ``SLIDE_SIGNS[d]`` of its
    coordinate, by the slide's own force check (``slide.slide_forces``: the other two fingers
    hold the weight and the sliding finger's kinetic friction). Only the contacts where
    ``holds`` (a strict grasp) are checked; the rest are False."""
    K, T = len(lattice.cs), len(lattice.ts)
    S = np.zeros((len(SLIDE_SIGNS), K, K, K, T), dtype=bool)
    drags = [drag_of(model, posture.faces[finger], sign) for sign in SLIDE_SIGNS]
    for k in zip(*np.nonzero(holds), strict=True):
        contacts = Contacts(posture, tuple(float(lattice.cs[j]) for j in k))
        rest = GraspPlan.from_contacts(model, contacts, prim, sliding=finger)  # both ways
        for d, drag in enumerate(drags):
            plan = GraspPlan.from_contacts(model, contacts, prim, sliding=finger, drag=drag)
            for t, angle in enumerate(lattice.ts):
                S[(d, *k, t)] = slide_forces(plan, rest, finger, float(angle), model, prim,
                                             max_push_n) is None
    return S


def way_table(model: HandModel, lattice: Lattice, finger: int) -> np.ndarray:
    """``W[s, k, k2, x, z, t]``: with the object at that pose, ``finger`` lifted off side
    ``SIDES[s]`` at coordinate ``cs[k]`` can travel to hover over the other side at ``cs[k2]``
    through its joint space, as a flip plans it (``Flip._path``: its lift and hover joint
    angles, with their elbow branches, and a chain of free cells of ``FreeSpace`` between them,
    which exists exactly when both lie in one of its connected pieces). The lift takes either
    elbow branch (the cell does not say which the finger has), so the table may allow a flip
    that a finger on the other branch cannot make. For an upright pole the way passes under its
    lower end, so it exists only with the pole held high enough above the palm."""
    K, X, Z, T = lattice.shape
    W = np.zeros((2, K, K, X, Z, T), dtype=bool)
    shape, r = model.shape, model.tip_radius
    for (ix, x), (iz, z), (it, t) in itertools.product(
            enumerate(lattice.xs), enumerate(lattice.zs), enumerate(lattice.ts)):
        pose = np.array([x, z, t])
        R = rotation(t)
        space = FreeSpace(model, finger, pose, AIR_M)
        lifts, hovers = [], []  # per side: the labels of each coordinate's free piece
        for face in SIDES:
            reach = shape.half_extent(face) - 2 * r
            lift_k, hover_k = [], []
            for c in lattice.cs:
                c = float(c)
                # the lift and the hover are the same point off the face: its joint angles
                # with each elbow branch preferred, and their free pieces (0: none)
                point = hover(shape.half_x, shape.half_z, face, c, r + LIFT_M)
                label = {}
                for elbow in (1, -1):
                    q = ik_clear(model, finger, point, pose, R, model.clearance, prefer=elbow)
                    label[elbow] = space.component(q) if q is not None and space.ok(q) else 0
                lift_k.append(set(label.values()) - {0})
                touch = ik_clear(model, finger, hover(shape.half_x, shape.half_z, face, c,
                                                      r - PRESS_M), pose, R, model.clearance)
                hover_k.append(label[1 if touch[1] >= 0 else -1]
                               if touch is not None and abs(c) <= reach else 0)
            lifts.append(lift_k)
            hovers.append(hover_k)
        for s in range(2):
            for k, k2 in itertools.product(range(K), repeat=2):
                W[s, k, k2, ix, iz, it] = hovers[1 - s][k2] in lifts[s][k]
    return W


def finger_table(model: HandModel, lattice: Lattice, margin: float = 0.1) -> np.ndarray:
    """``F[i, s, k, x, z, t]``: finger ``i`` alone touches side ``SIDES[s]`` at coordinate
    ``cs[k]`` with the object at that pose (reach, joint limits with ``margin``, links clear)."""
    K, X, Z, T = lattice.shape
    F = np.zeros((3, 2, K, X, Z, T), dtype=bool)
    r = model.tip_radius
    for (ix, x), (iz, z), (it, t) in itertools.product(
            enumerate(lattice.xs), enumerate(lattice.zs), enumerate(lattice.ts)):
        pose = np.array([x, z, t])
        R = rotation(t)
        for s, face in enumerate(SIDES):
            for k, c in enumerate(lattice.cs):
                point, inward = model.shape.local_contact(face, float(c))
                target = pose[:2] + R @ (point - r * inward)
                for i, f in enumerate(model.fingers):
                    for elbow in (1, -1):
                        qi = f.ik(target, elbow)
                        if (qi is not None and f.within_limits(qi, margin)
                                and model.finger_gap(i, qi, pose) >= model.clearance):
                            F[i, s, k, ix, iz, it] = True
                            break
    return F


@dataclass
class PoseGraph:
    """The nodes (cells the hand holds) and the weighted, directed edges between them."""

    lattice: Lattice
    postures: list[Posture]
    ids: np.ndarray  # (P, K, K, K, X, Z, T) node id, -1 where the hand does not hold
    matrix: sparse.csr_matrix  # (n, n) edge weights (s)
    build_s: float = 0.0
    _fields: OrderedDict = field(default_factory=OrderedDict, repr=False, compare=False)

    @property
    def nodes(self) -> int:
        return self.matrix.shape[0]

    @property
    def edges(self) -> int:
        """Directed edges: a repose or a flip counts once each way, a slide only where friction
        allows it."""
        return self.matrix.nnz

    @property
    def bytes(self) -> int:
        m = self.matrix
        return self.ids.nbytes + m.data.nbytes + m.indices.nbytes + m.indptr.nbytes

    def cell(self, contacts: Contacts, pose: np.ndarray, reach: float = 0.0) -> tuple | None:
        """The index of the cell of ``contacts`` at ``pose`` in ``ids`` (posture, three contact
        cells, pose cell), or None off the lattice; ``reach``: see ``Lattice.contact_cell``."""
        if contacts.posture not in self.postures:
            return None
        pc = self.lattice.pose_cell(pose)
        ks = [self.lattice.contact_cell(c, reach) for c in contacts.coords]
        if pc is None or any(k is None for k in ks):
            return None
        return (self.postures.index(contacts.posture), *ks, *pc)

    def near(self, cell: tuple) -> np.ndarray:
        """The nodes of ``cell`` and of the cells one step from it along any of its contact and
        pose axes (the same posture): where a state's own cell holds no node, the ones the
        hand holds next to it."""
        box = tuple(slice(max(0, c - 1), c + 2) for c in cell[1:])
        ids = self.ids[(cell[0], *box)]
        return ids[ids >= 0]

    def nodes_at(self, pose_cell: tuple) -> np.ndarray:
        """The nodes (any posture and contacts) at a pose cell, or at a box of them (slices)."""
        ids = self.ids[(..., *pose_cell)]
        return ids[ids >= 0]

    def distances_to(self, goal: np.ndarray, cut: set[tuple[int, int]] = frozenset(),
                     spent: set[int] = frozenset()) -> np.ndarray:
        """Shortest time (s) from every node to any node at the goal's pose cell, or where
        that cell holds none, at the pose cells one step from it (inf where none is reachable;
        all inf off the lattice), without the edges ``cut`` (node pairs, from the first to the
        second) and without the end nodes ``spent``."""
        cell = self.lattice.pose_cell(goal)
        if cell is None:
            return np.full(self.nodes, np.inf)
        targets = self.nodes_at(cell)
        if targets.size == 0:  # the goal is held, but no grasp on the lattice at its cell centre
            targets = self.nodes_at(tuple(slice(max(0, c - 1), c + 2) for c in cell))
        if spent:
            targets = targets[~np.isin(targets, list(spent))]
        if targets.size == 0:
            return np.full(self.nodes, np.inf)
        # from the targets along the reversed edges: the time from every node to them
        reverse = self.reverse
        if cut:  # an infinite weight: no path goes through the edge
            reverse = reverse.copy()
            for u, v in cut:  # the edge u -> v is v's row in the reverse
                row = slice(reverse.indptr[v], reverse.indptr[v + 1])
                reverse.data[row][reverse.indices[row] == u] = np.inf
        return csgraph.dijkstra(reverse, directed=True, indices=targets, min_only=True)

    def to_goal(self, goal: np.ndarray) -> np.ndarray:
        """``distances_to(goal)``, kept for the last ``FIELDS_KEPT`` goal cells (one Dijkstra
        per goal cell, shared by everything that walks or reads this graph)."""
        key = self.lattice.pose_cell(goal)
        if key not in self._fields:
            self._fields[key] = self.distances_to(goal)
            if len(self._fields) > FIELDS_KEPT:
                self._fields.popitem(last=False)
        self._fields.move_to_end(key)
        return self._fields[key]

    @functools.cached_property
    def reverse(self) -> sparse.csr_matrix:
        """The edges turned round (row v holds the edges into v), built once."""
        return self.matrix.T.tocsr()

    def successors(self, cell: tuple, action) -> list[tuple]:
        """The cells a mid-level ``action`` (``task.actions.Action``) leads to from ``cell``
        along one edge: a repose or a slide one cell along its axis, a flip to every contact
        cell of the finger on the other face (the cells off the lattice left out)."""
        c = list(cell)
        K = len(self.lattice.cs)
        if action.kind == "repose":
            axis = int(np.argmax(np.abs(action.delta)))
            c[4 + axis] += 1 if action.delta[axis] > 0 else -1
            out = [tuple(c)]
        elif action.kind == "slide":
            c[1 + action.finger] += 1 if action.dc > 0 else -1
            out = [tuple(c)]
        elif action.kind == "flip":
            faces = list(self.postures[c[0]].faces)
            faces[action.finger] = SIDES[1 - SIDES.index(faces[action.finger])]
            other = Posture(tuple(faces))
            if other not in self.postures:
                return []
            out = []
            for k in range(K):
                c2 = list(c)
                c2[0], c2[1 + action.finger] = self.postures.index(other), k
                out.append(tuple(c2))
        else:
            return []
        dims = self.ids.shape
        return [t for t in out if all(0 <= v < n for v, n in zip(t, dims, strict=True))]

    def weight(self, u: int, v: int) -> float:
        """The time of the edge from node ``u`` to node ``v`` (inf where there is none)."""
        m = self.matrix
        row = slice(m.indptr[u], m.indptr[u + 1])
        hit = np.flatnonzero(m.indices[row] == v)
        return float(m.data[row][hit[0]]) if hit.size else math.inf


def contacts_of(model: HandModel, q: np.ndarray, pose: np.ndarray) -> Contacts:
    """The fingertips' side and place along the pole, from the joints and the pose."""
    tips_O = (model.tips(q) - pose[:2]) @ rotation(pose[2])
    faces = tuple(Face.RIGHT if t[0] > 0 else Face.LEFT for t in tips_O)
    return Contacts(Posture(faces), tuple(float(t[1]) for t in tips_O))


def _plain(section) -> dict:
    return (OmegaConf.to_container(section, resolve=True, enum_to_str=True)
            if isinstance(section, DictConfig) else section)


def graph_key(cfg, params: SearchConfig) -> str:
    """A digest of everything that shapes the graph of ``cfg`` (a composed config, or the plain
    dict a worker process gets) at the resolutions of ``params``."""
    parts = {k: _plain(cfg[k]) for k in ("hand", "object", "primitives")}
    task = typed(cfg["task"], TaskConfig)
    parts["workspace"] = [task.workspace_x_m, task.workspace_z_m, task.workspace_theta_rad]
    parts["resolution"] = [params.resolution_m, params.resolution_rad,
                           params.contact_resolution_m]
    parts["gravity"] = cfg["sim"]["gravity_mps2"]
    parts["version"] = GRAPH_VERSION
    blob = json.dumps(parts, sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def save_graph(graph: PoseGraph, path: Path) -> None:
    lat, m = graph.lattice, graph.matrix
    tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")  # parallel builders do not collide
    np.savez_compressed(tmp, xs=lat.xs, zs=lat.zs, ts=lat.ts, cs=lat.cs, ids=graph.ids,
                        data=m.data, indices=m.indices, indptr=m.indptr,
                        postures=np.array([[int(f) for f in p.faces] for p in graph.postures]),
                        build_s=graph.build_s)
    tmp.replace(path)


def load_graph(path: Path) -> PoseGraph:
    with np.load(path) as z:
        lat = Lattice(z["xs"], z["zs"], z["ts"], z["cs"])
        ps = [Posture(tuple(Face(int(f)) for f in row)) for row in z["postures"]]
        n = int(z["indptr"].size - 1)
        m = sparse.csr_matrix((z["data"], z["indices"], z["indptr"]), shape=(n, n))
        return PoseGraph(lat, ps, z["ids"], m, float(z["build_s"]))


def check_size(model: HandModel, rules: TaskConfig, s: SearchConfig) -> None:
    """Refuse a lattice of more than ``learner.max_cells`` candidate cells before building."""
    lat = Lattice.build(model, Workspace.from_config(rules), s.resolution_m, s.resolution_rad,
                        s.contact_resolution_m)
    K, X, Z, T = lat.shape
    cells = 6 * K**3 * X * Z * T
    if cells > s.max_cells:
        raise ConfigError(f"the search lattice has {cells:,} cells (learner.resolution_m="
                          f"{s.resolution_m}, resolution_rad={s.resolution_rad}, "
                          f"contact_resolution_m={s.contact_resolution_m}), more than "
                          f"learner.max_cells={s.max_cells:,}")


_LOADED: dict[Path, PoseGraph] = {}  # graphs this process read from the cache, by file


def graph_path(params: SearchConfig, key: str) -> Path:
    """Where the graph of ``graph_key`` ``key`` is kept."""
    return Path(params.cache_dir) / f"graph-{key}.npz"


def cached_graph(cfg, params: SearchConfig) -> PoseGraph:
    """The graph of ``cfg`` at the resolutions of ``params``: read from ``params.cache_dir``
    (one file per ``graph_key``), or built and kept there."""
    path = graph_path(params, graph_key(cfg, params))
    if path in _LOADED:  # the environments of one worker process share one graph
        return _LOADED[path]
    if path.is_file():
        _LOADED[path] = graph = load_graph(path)
        return graph
    model = HandModel.from_config(typed(cfg["hand"], HandConfig), typed(cfg["object"],
                                                                         ObjectConfig),
                                  cfg["sim"]["gravity_mps2"])
    rules = typed(cfg["task"], TaskConfig)
    check_size(model, rules, params)
    graph = build_graph(model, typed(cfg["primitives"], PrimitivesConfig),
                        Workspace.from_config(rules), params.resolution_m,
                        params.resolution_rad, params.contact_resolution_m)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_graph(graph, path)
    return graph


def build_graph(model: HandModel, prim: PrimitivesConfig, workspace: Workspace,
                resolution_m: float, resolution_rad: float, contact_resolution_m: float
                ) -> PoseGraph:
    """The graph at these resolutions (see the module docstring)."""
    start = time.perf_counter()
    lat = Lattice.build(model, workspace, resolution_m, resolution_rad, contact_resolution_m)
    K, X, Z, T = lat.shape
    ps = postures(model)
    F = finger_table(model, lat)
    palm = np.zeros((X, Z, T), dtype=bool)
    for ix, iz, it in itertools.product(range(X), range(Z), range(T)):
        palm[ix, iz, it] = model.palm_gap(np.array([lat.xs[ix], lat.zs[iz], lat.ts[it]])) \
            >= model.clearance
    valid = np.zeros((len(ps), K, K, K, X, Z, T), dtype=bool)
    squeezes = np.zeros((len(ps), K, K, K), dtype=bool)
    for p, posture in enumerate(ps):
        s = [SIDES.index(f) for f in posture.faces]
        squeeze = squeezes[p]
        for k in itertools.product(range(K), repeat=3):
            squeeze[k] = strict_hold(model, Contacts(posture, tuple(float(lat.cs[j])
                                                                    for j in k)), prim,
                                     firm=True)
        valid[p] = (squeeze[:, :, :, None, None, None]
                    & F[0, s[0]][:, None, None] & F[1, s[1]][None, :, None]
                    & F[2, s[2]][None, None, :] & palm)
    ids = np.full(valid.shape, -1, dtype=np.int32)
    ids[valid] = np.arange(int(valid.sum()))
    rows, cols, weights = [], [], []

    def link(a: np.ndarray, b: np.ndarray, w: float, both: bool = True) -> None:
        ok = (a >= 0) & (b >= 0)
        for u, v in ((a, b), (b, a)) if both else ((a, b),):
            rows.append(u[ok])
            cols.append(v[ok])
            weights.append(np.full(int(ok.sum()), w))

    repose = [math.ceil(resolution_m / prim.repose_dx_m - 1e-9),
              math.ceil(resolution_m / prim.repose_dz_m - 1e-9),
              math.ceil(resolution_rad / prim.repose_dtheta_rad - 1e-9)]
    for axis, n in zip((4, 5, 6), repose, strict=True):  # x, z, angle
        a = np.moveaxis(ids, axis, 0)
        link(a[:-1], a[1:], n * prim.repose_duration_s)
    if prim.slide:  # directed: friction allows some slides only one way
        n = math.ceil(contact_resolution_m / prim.slide_dc_m - 1e-9)
        for p, posture in enumerate(ps):
            for f in range(3):
                table = slide_table(model, lat, posture, f, prim, squeezes[p])
                a = np.moveaxis(ids[p], f, 0)
                for sign, S in zip(SLIDE_SIGNS, table, strict=True):
                    S = np.moveaxis(S, f, 0)[:, :, :, None, None, :]  # (K_f, K, K, 1, 1, T)
                    src, dst = (a[:-1], a[1:]) if sign > 0 else (a[1:], a[:-1])
                    go = S[:-1] & S[1:]  # the force check at both ends of the edge
                    link(np.where(go, src, -1), dst, n * prim.slide_duration_s, both=False)
    if prim.flip:
        ways = {f: way_table(model, lat, f) for f in FLIP_FINGERS}
        for p, posture in enumerate(ps):
            for f in FLIP_FINGERS:
                stay = [j for j in range(3) if j != f]
                if posture.faces[stay[0]] == posture.faces[stay[1]]:
                    continue  # the staying pair must oppose each other
                other = Posture(tuple(SIDES[1 - SIDES.index(face)] if j == f else face
                                      for j, face in enumerate(posture.faces)))
                if other not in ps:
                    continue
                q = ps.index(other)
                held = pair_table(model, lat, posture, f, prim)[:, :, None, None, :]
                way = ways[f][SIDES.index(posture.faces[f])]  # (K_f, K_f', X, Z, T)
                src = np.moveaxis(ids[p], f, 0)  # (K_f, K_a, K_b, X, Z, T)
                dst = np.moveaxis(ids[q], f, 0)
                for k, k2 in itertools.product(range(K), repeat=2):
                    go = held & way[k, k2][None, None]
                    link(np.where(go, src[k], -1), dst[k2], prim.flip_duration_s, both=False)
    n = int(valid.sum())
    r, c, w = (np.concatenate(v) if v else np.zeros(0) for v in (rows, cols, weights))
    matrix = sparse.coo_matrix((w, (r, c)), shape=(n, n)).tocsr()
    return PoseGraph(lat, ps, ids, matrix, time.perf_counter() - start)
