"""The graph-search baseline (paper section IV-A): Dijkstra over held cells, executed with the
same primitives in physics, replanned from the observed state.

``train`` builds the graph of ``task.graph`` (or loads it from the on-disk cache, keyed by
everything that shapes it) and logs its size, build time and memory; no frames are learned. The
policy acts in the mid-level environment with its 14 actions, so its episodes are run, judged
and logged exactly as PPO's. At each step it reads its state from the observation alone:

- the object pose ``X_t`` and the goal ``X_g``; the contacts from the joints (the fingertips'
  place on the object: which side, and where along it);
- the shortest time to the goal's pose cell from every node (one Dijkstra per goal cell,
  cached); where no grasp on the lattice holds the object at that cell's centre (the goal
  itself is held, off the lattice's points), to the pose cells next to it;
- it carries out the best edge out of its current cell (the least edge time plus shortest
  time beyond; the graph is directed, so only edges that go that way count): the mid-level
  action of that edge (a 2 cm cell is two 1 cm reposes), repeated until the observed cell is
  the edge's end. When the feasibility filter refuses the best edge's action (the cells allow
  more flips than the continuous state does), or an edge does not arrive, that edge is cut
  from the episode's
  graph and the distances are planned again (one Dijkstra, about 10 ms), so the walk does not
  come back to try it again from a neighbour;
- at the goal cell (from the cells next to it on, where it holds no node), and wherever the
  graph has no path, it searches locally in real time (LRTA*, Korf 1990): over the places it
  has been (the posture, the fingertips' places and the pose; within half a slide's or a
  repose's step of a place met before is that place), it takes the allowed action with the
  least cost (one per action, two per flip) plus the estimate beyond, and raises the estimate
  of the state it leaves to that least. Estimates
  start at the distance to the goal in tolerances, so it first takes the repose that brings
  the object closest to the goal (the cell is up to half a cell from the goal itself); where
  the reposes towards the goal are refused, it slides the fingers to grasps not tried yet
  instead of going back and forth. When it comes back to a node of the goal cell no closer to
  the goal than it was there before, that node is spent: the walk plans on to the goal cell's
  other nodes;
- an action that failed to arrive from off the graph is not retried from there; on the graph,
  only cut edges are left out, so that the walk and its distances agree.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torchrl.envs import EnvBase

from inhand_exp.config import PrimitivesConfig, SearchConfig, TaskConfig, typed
from inhand_exp.control.grasp import Contacts, Posture
from inhand_exp.control.hand import HandModel
from inhand_exp.envs.primitive_env import PrimitiveEnv
from inhand_exp.learn.checkpoint import read_checkpoint, save_checkpoint, stamped, trained_with
from inhand_exp.learn.registry import Progress
from inhand_exp.task.actions import Action, action_table
from inhand_exp.task.graph import (
    SIDES,
    PoseGraph,
    cached_graph,
    contacts_of,
    graph_key,
    graph_path,
)
from inhand_exp.task.rules import to_go


def from_config(cfg) -> Search:
    return Search(cfg)


class Search:
    """The graph, and a policy that walks it (see the module docstring)."""

    per_action_log = True
    stochastic = False  # the graph's shortest path
    env_class = PrimitiveEnv  # it walks the graph with the mid-level actions

    def __init__(self, cfg):
        self.cfg = cfg
        self.params = typed(cfg.learner, SearchConfig)
        self.prim = typed(cfg.primitives, PrimitivesConfig)
        self.rules = typed(cfg.task, TaskConfig)
        self.model = HandModel.from_config(cfg.hand, cfg.object, cfg.sim.gravity_mps2)
        self.actions = action_table(self.prim)
        self.key = graph_key(cfg, self.params)
        self.cache = graph_path(self.params, self.key)
        self.graph: PoseGraph | None = None
        self.iteration, self.frames = 0, 0
        self.trained_with: list[str] | None = None
        self.stats: dict[str, float] = {}

    # --- the graph --------------------------------------------------------------------------

    def ensure_graph(self) -> PoseGraph:
        """The graph, loaded from the cache or built (and cached)."""
        if self.graph is None:
            cached, t = self.cache.is_file(), time.perf_counter()
            self.graph = g = cached_graph(self.cfg, self.params)
            if cached:
                self.stats["load_s"] = time.perf_counter() - t
            self.stats.update(nodes=g.nodes, edges=g.edges, build_s=g.build_s,
                              memory_mb=g.bytes / 1e6)
        return self.graph

    @property
    def policy(self) -> SearchPolicy:
        return SearchPolicy(self.ensure_graph(), self.model, self.prim, self.rules,
                            self.actions)

    def train(self, env: EnvBase, total_frames: int, progress: Progress | None = None,
              checkpoint: Path | None = None, checkpoint_every: int = 10) -> None:
        """Build (or load) the graph; nothing is learned from ``env``."""
        t = time.perf_counter()
        self.ensure_graph()
        self.iteration += 1
        self.frames += total_frames  # the budget is spent: the graph is the whole "training"
        if progress is not None:
            progress(self.iteration, {"frames": self.frames, "mean_reward": 0.0,
                                      "success_rate": 0.0, "drop_rate": 0.0,
                                      "collect_s": 0.0, "learn_s": time.perf_counter() - t})
        if checkpoint is not None:
            self.save(checkpoint)

    def save(self, path: Path) -> None:
        save_checkpoint(stamped({"learner": "search", "iteration": self.iteration,
                                 "frames": self.frames, "graph_key": self.key},
                                self.trained_with), path)

    def load(self, path: Path) -> None:
        state = read_checkpoint(path, "search")
        self.iteration, self.frames = int(state["iteration"]), int(state["frames"])
        self.trained_with = trained_with(state)


@dataclass
class _Walk:
    """One environment's episode: its goal, the edge under way and the edges that failed."""

    goal: tuple[float, float, float]
    bare: bool = False  # the goal's pose cell holds no node: the plan ends next to it
    edge: tuple | None = None  # (source node, target cell, action, steps taken, step budget)
    blocked: set = field(default_factory=set)  # (target cell, action) failed from off the graph
    cut: set = field(default_factory=set)  # edges (node pairs) that failed or were refused
    spent: set = field(default_factory=set)  # goal-cell nodes whose last reposes got stuck
    closest: dict = field(default_factory=dict)  # goal-cell node -> least error seen there
    estimate: dict = field(default_factory=dict)  # local state -> raised cost to go (LRTA*)
    states: list = field(default_factory=list)  # the local states met: (posture, scaled place)
    local: bool = False  # reached the cells next to a goal cell without a node: LRTA* only
    field: np.ndarray | None = None  # distances to the goal without the cut edges


class SearchPolicy:
    """Writes ``action`` for a batch of mid-level observations (see the module docstring)."""

    def __init__(self, graph: PoseGraph, model: HandModel, prim: PrimitivesConfig,
                 rules: TaskConfig, actions: tuple[Action, ...]):
        self.graph, self.model, self.prim, self.rules = graph, model, prim, rules
        self.actions = actions
        self.walks: dict[int, _Walk] = {}
        lat = graph.lattice
        steps = {"x": abs(lat.xs[1] - lat.xs[0]) if len(lat.xs) > 1 else 1.0,
                 "z": abs(lat.zs[1] - lat.zs[0]) if len(lat.zs) > 1 else 1.0,
                 "t": abs(lat.ts[1] - lat.ts[0]) if len(lat.ts) > 1 else 1.0,
                 "c": abs(lat.cs[1] - lat.cs[0]) if len(lat.cs) > 1 else 1.0}
        self.budget = {}  # mid-level actions one edge of each action takes, plus one spare
        for a in actions:
            if a.kind == "repose":
                axis = int(np.argmax(np.abs(a.delta)))
                self.budget[a.index] = math.ceil(steps["xzt"[axis]] / abs(a.delta[axis])) + 1
            elif a.kind == "slide":
                self.budget[a.index] = math.ceil(steps["c"] / abs(a.dc)) + 1
            else:
                self.budget[a.index] = 1

    def __call__(self, td):
        flat = td.reshape(-1)
        obs = flat["observation"].double().numpy()
        mask = flat["action_mask"].numpy()
        out = [self.act(i, obs[i], mask[i]) for i in range(len(obs))]
        td.set("action", torch.tensor(out, dtype=torch.int64).reshape(td.batch_size))
        return td

    # --- reading the state ----------------------------------------------------------------------

    def contacts(self, q: np.ndarray, pose: np.ndarray) -> Contacts:
        """The fingertips' side and place along the pole, from the joints and the pose."""
        return contacts_of(self.model, q, pose)

    def cell(self, contacts: Contacts, pose: np.ndarray) -> tuple | None:
        return self.graph.cell(contacts, pose, self.model.shape.half_z)

    # --- acting ---------------------------------------------------------------------------------

    def successors(self, cell: tuple, a: Action) -> list[tuple]:
        """The cells action ``a`` leads to from ``cell`` along one edge."""
        return self.graph.successors(cell, a)

    def act(self, i: int, obs: np.ndarray, mask: np.ndarray) -> int:
        q, pose, goal = obs[:6], obs[12:15], obs[15:18]
        walk = self.walks.get(i)
        if walk is None or walk.goal != tuple(np.round(goal, 9)):
            walk = self.walks[i] = _Walk(tuple(np.round(goal, 9)), self._bare_goal_cell(goal))
        cell = self.cell(self.contacts(q, pose), pose)
        ids = self.graph.ids
        if walk.edge is not None:
            source, target, a, steps, budget = walk.edge
            if cell == target:
                walk.edge = None
            elif steps < budget and mask[a]:
                walk.edge = (source, target, a, steps + 1, budget)
                return a
            else:  # it did not arrive: plan around it
                self._cut(walk, source, [target], a, goal)
                walk.edge = None
        d = walk.field if walk.field is not None else self.graph.to_goal(goal)
        here = int(ids[cell]) if cell is not None else -1
        if here >= 0 and d[here] == 0.0 and self._stuck(walk, here, pose, goal):
            d = self._replan(walk, goal)
        if walk.bare and (walk.local or (here >= 0 and d[here] == 0.0)):
            walk.local = True  # next to a goal cell without a node: from here on, locally
            return self.explore(walk, q, pose, goal, mask)
        while cell is not None and not (here >= 0 and d[here] == 0.0):
            best, choice = math.inf, None
            for a in self.actions:
                for t in self.successors(cell, a):
                    n = int(ids[t])
                    if n < 0 or (here, n) in walk.cut or (here < 0 and (t, a.index)
                                                          in walk.blocked):
                        continue
                    # on the graph, along its edges only (a slide friction forbids is none)
                    cost = d[n] + self.graph.weight(here, n) if here >= 0 else d[n]
                    if cost < best:
                        best, choice = cost, (t, a)
            if choice is None or not math.isfinite(best):
                break
            t, a = choice
            if mask[a.index]:
                walk.edge = (here, t, a.index, 1, self.budget[a.index])
                return a.index
            # the filter refuses the best edge here (a flip the graph's cells allow, say):
            # plan again without this action's edges out of here
            d = self._cut(walk, here, self.successors(cell, a), a.index, goal)
        return self.explore(walk, q, pose, goal, mask)

    def _bare_goal_cell(self, goal: np.ndarray) -> bool:
        """Whether the goal's pose cell holds no node (the plan ends in the cells next to it,
        see ``PoseGraph.distances_to``)."""
        cell = self.graph.lattice.pose_cell(goal)
        return cell is not None and self.graph.nodes_at(cell).size == 0

    def _cut(self, walk: _Walk, source: int, targets: list[tuple], action: int,
             goal: np.ndarray) -> np.ndarray:
        """Leave the edges from node ``source`` to ``targets`` out of the walk's plan from now
        on (from off the graph, ``source`` -1: those targets by that action), and return the
        distances planned again without them."""
        ids = self.graph.ids
        if source < 0:
            walk.blocked.update((t, action) for t in targets)
            return walk.field if walk.field is not None else self.graph.to_goal(goal)
        walk.cut.update((source, int(ids[t])) for t in targets if ids[t] >= 0)
        return self._replan(walk, goal)

    def _replan(self, walk: _Walk, goal: np.ndarray) -> np.ndarray:
        walk.field = self.graph.distances_to(goal, walk.cut, walk.spent)
        return walk.field

    def _stuck(self, walk: _Walk, node: int, pose: np.ndarray, goal: np.ndarray) -> bool:
        """Whether the last reposes from goal-cell node ``node`` got stuck: the walk is back
        there no closer to the goal than before (a repose the filter refuses here, say, so
        that the closest allowed one leaves the cell and the walk comes back). Such a node is
        spent: the walk goes on to the goal cell's other nodes (other contacts, or another
        posture), from which the last reposes may be allowed."""
        error = to_go(pose, goal, self.rules)
        seen = walk.closest.get(node)
        if seen is not None and error >= seen - 1e-9:
            walk.spent.add(node)
            return True
        walk.closest[node] = error
        return False

    # --- off the plan: a local real-time search ---------------------------------------------

    FLIP_COST = 2.0  # a flip takes about twice a repose's time, and it risks more

    def scaled(self, contacts: Contacts, pose: np.ndarray) -> np.ndarray:
        """The fingertips' places in slide steps and the pose in repose steps."""
        steps = (self.prim.repose_dx_m, self.prim.repose_dz_m, self.prim.repose_dtheta_rad)
        return np.concatenate([np.asarray(contacts.coords) / self.prim.slide_dc_m,
                               np.asarray(pose) / np.asarray(steps)])

    @staticmethod
    def met(walk: _Walk, posture: Posture, place: np.ndarray) -> int | None:
        """The local state met before within half a step of ``place`` in every coordinate
        (the nearest), or None."""
        best, found = 0.5, None
        for n, (p, v) in enumerate(walk.states):
            if p == posture:
                gap = float(np.max(np.abs(v - place)))
                if gap < best:
                    best, found = gap, n
        return found

    def key(self, walk: _Walk, contacts: Contacts, pose: np.ndarray) -> int:
        """The local state of the observed grasp and pose: the one met before within half a
        step (a slide's, a repose's) of it, else a new one. States are the places the walk
        has been, not cells of a fixed grid: the reposes move the object by whole steps from
        wherever it was, so a grid's edges would fall where it stops (a graph cell's centre
        lies half a repose step off the grid of 1 cm steps) and the same place would get a
        new key at every visit, which keeps LRTA* from learning (pairs that went back and
        forth between two poses for 100 actions)."""
        place = self.scaled(contacts, pose)
        n = self.met(walk, contacts.posture, place)
        if n is None:
            walk.states.append((contacts.posture, place))
            n = len(walk.states) - 1
        return n

    def after(self, walk: _Walk, here: int, a: Action) -> int | tuple | None:
        """The local state action ``a`` leads to from state ``here``: one met before, or the
        predicted place when none was (a key no estimate is stored under yet); None for the
        cube's release and land, which the local search leaves alone."""
        posture, place = walk.states[here]
        place = place.copy()
        if a.kind == "repose":
            axis = int(np.argmax(np.abs(a.delta)))
            place[3 + axis] += 1.0 if a.delta[axis] > 0 else -1.0
        elif a.kind == "slide":
            place[a.finger] += 1.0 if a.dc > 0 else -1.0
        elif a.kind == "flip":
            faces = list(posture.faces)
            faces[a.finger] = SIDES[1 - SIDES.index(faces[a.finger])]
            posture = Posture(tuple(faces))
        else:
            return None
        n = self.met(walk, posture, place)
        return n if n is not None else (posture, tuple(place))

    def explore(self, walk: _Walk, q: np.ndarray, pose: np.ndarray, goal: np.ndarray,
                mask: np.ndarray) -> int:
        """One step of LRTA* from the observed state (see the module docstring)."""
        here = self.key(walk, self.contacts(q, pose), pose)
        allowed = [a for a in self.actions if mask[a.index]] or list(self.actions)
        best, choice = math.inf, None
        for a in allowed:
            there = self.after(walk, here, a)
            if there is None:
                continue
            beyond = walk.estimate.get(there)
            if beyond is None:
                beyond = to_go(pose + np.asarray(a.delta), goal, self.rules)
            cost = (self.FLIP_COST if a.kind == "flip" else 1.0) + beyond
            if cost < best:
                best, choice = cost, a
        if choice is None:
            return self.closest_repose(pose, goal, mask)
        walk.estimate[here] = max(walk.estimate.get(here, to_go(pose, goal, self.rules)), best)
        return choice.index

    def closest_repose(self, pose: np.ndarray, goal: np.ndarray, mask: np.ndarray) -> int:
        """The allowed action whose pose change brings the object closest to the goal (a
        slide or flip, which moves nothing, ranks as staying)."""
        def after(a: Action) -> float:
            return to_go(pose + np.asarray(a.delta), goal, self.rules)

        allowed = [a for a in self.actions if mask[a.index]] or list(self.actions)
        return min(allowed, key=after).index

