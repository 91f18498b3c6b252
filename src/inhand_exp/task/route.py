"""The search graph's route time to the goal, as a potential for shaping the mid level's reward.

``task.reward_route`` pays, for each action, the seconds of the graph's shortest route to the goal
that the action saved (``RouteTime`` before minus after, read from the simulated state). It is a
potential-based shaping (Ng et al. 1999), so the best policy stays the best; what it adds over
the progress shaping (``task.reward_progress``, the distance to the goal itself) is the way
there: a goal that needs a flip first needs the pole raised high enough for the finger to pass
under its end, away from the goal, and the route says so. The graph is the search baseline's
(``task.graph``: the controllers' own model at the paper's resolution, flips only where the
finger has a way round the end), read from its cache or built there once. The policy does not
see the graph: it shapes the training reward only.

``task.route_advice`` shows the same graph to the policy instead (``RouteAdvice``): appended to
the observation, the route time from the observed state and, per action, how much longer the
route is when it goes on by that action's edges. It is the search baseline's own reading of the
state, offered to the policy to use or not; the paper's policy sees no such thing.
"""

from __future__ import annotations

import math

import numpy as np

from inhand_exp.control.hand import HandModel
from inhand_exp.task.graph import PoseGraph, contacts_of


class RouteTime:
    """Seconds of primitives along the graph's shortest route from a state to the goal's cell,
    at most ``cap_s`` (also where the graph has no route, or no node near the state).

    The state's cell is read from the joints and the object pose, as the search reads it. Where
    that cell holds no node (the grasp holds at the state but not at the cell's centre), the
    nearest nodes stand in (``PoseGraph.near``), the best of them counting.
    """

    def __init__(self, graph: PoseGraph, model: HandModel, cap_s: float):
        if not cap_s > 0:
            raise ValueError(f"cap_s must be > 0, got {cap_s}")
        self.graph, self.model, self.cap_s = graph, model, cap_s

    def __call__(self, q: np.ndarray, pose: np.ndarray, goal: np.ndarray) -> float:
        return min(self.cap_s, state_route(self.graph, self.model, q, pose, goal)[3])


def state_route(g: PoseGraph, model: HandModel, q: np.ndarray, pose: np.ndarray,
                goal: np.ndarray) -> tuple[tuple | None, int, np.ndarray | None, float]:
    """The state's cell (None off the lattice), its node (-1: none), the distances to the
    goal's cell and the state's route time (inf: no route): the node's distance or, where the
    cell holds no node, the best of the nearest nodes' (``PoseGraph.near``)."""
    cell = g.cell(contacts_of(model, q, pose), pose, model.shape.half_z)
    if cell is None:
        return None, -1, None, math.inf
    d = g.to_goal(goal)
    here = int(g.ids[cell])
    nodes = np.array([here]) if here >= 0 else g.near(cell)
    return cell, here, d, float(d[nodes].min()) if nodes.size else math.inf


ADVICE_SCALE_S = 2.0  # route seconds per unit of an action's advice (two edges of reposes)


class RouteAdvice:
    """The graph's view of a state, for the policy's observation (``task.route_advice``):
    ``1 + len(actions)`` floats.

    - the route time from the state to the goal's cell over ``cap_s`` (1: no route, off the
      graph, or longer than ``cap_s``);
    - per action, the extra route seconds when the route goes on by that action's edges out of
      the state's cell (the edge's time plus the time from its end, least over its ends, minus
      the state's route time), over ``ADVICE_SCALE_S``, clipped to [-1, 1]: 0 along a shortest
      route, 1 where the action has no edge or the graph no route. Off the graph's nodes (the
      state's cell holds none) the edges' own times are not known and the ends' times count.

    The state is read as the search reads it: the contacts from the joints and the pose, both
    observed. The feasibility filter is not consulted (the mask says that).
    """

    def __init__(self, graph: PoseGraph, model: HandModel, actions, cap_s: float):
        if not cap_s > 0:
            raise ValueError(f"cap_s must be > 0, got {cap_s}")
        self.graph, self.model, self.actions, self.cap_s = graph, model, actions, cap_s
        self.size = 1 + len(actions)

    def __call__(self, q: np.ndarray, pose: np.ndarray, goal: np.ndarray) -> np.ndarray:
        g, out = self.graph, np.ones(self.size)
        cell, here, d, now = state_route(g, self.model, q, pose, goal)
        if not math.isfinite(now):
            return out
        out[0] = min(now, self.cap_s) / self.cap_s
        for a in self.actions:
            best = math.inf
            for t in g.successors(cell, a):
                n = int(g.ids[t])
                if n >= 0:
                    best = min(best, d[n] + g.weight(here, n) if here >= 0 else d[n])
            if math.isfinite(best):
                out[1 + a.index] = min(1.0, max(-1.0, (best - now) / ADVICE_SCALE_S))
        return out
