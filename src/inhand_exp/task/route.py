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
"""

from __future__ import annotations

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
        g = self.graph
        cell = g.cell(contacts_of(self.model, q, pose), pose, self.model.shape.half_z)
        if cell is None:
            return self.cap_s
        here = int(g.ids[cell])
        nodes = np.array([here]) if here >= 0 else g.near(cell)
        if nodes.size == 0:
            return self.cap_s
        return float(min(self.cap_s, g.to_goal(goal)[nodes].min()))
