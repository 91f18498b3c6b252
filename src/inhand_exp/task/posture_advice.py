"""What the fingers' posture can still do for the goal, for the policy's observation
(``task.posture_advice``): two flags, read from the observed state by the controllers' own
feasibility model (``task.goals``), as the goal sets flag their pairs.

- ``flip``: no grasp of the posture the fingers are in holds the object at the goal
  (``goals.needs_flip``); only a flip changes that.
- ``lone``: it holds it there only with the lone finger lower on the pole than it is now
  (``goals.lone_descends``), the slide friction forbids on a pole near upright; it takes two
  flips round a slide, or a tilt beyond about 1 rad.

The policy sees the posture in its grasp features, but whether some grasp of it holds the
object at a goal is a search over grasps that a network would have to learn from rare
episodes; the flags give it that answer. They change only with the posture (a flip) and the
lone finger's place (its slides), so each answer is kept for the episode's goal, the lone
finger's place rounded to ``step_m``.
"""

from __future__ import annotations

import numpy as np

from inhand_exp.control.grasp import Contacts
from inhand_exp.control.hand import HandModel
from inhand_exp.control.sample import elongated, lone_finger
from inhand_exp.task.goals import LONE_SLACK_M, holds_near


class PostureAdvice:
    """``(contacts, goal) -> [flip, lone]`` (floats 0 or 1; see the module docstring)."""

    size = 2

    def __init__(self, model: HandModel, tol: tuple[float, float], step_m: float = 0.0025):
        if not step_m > 0:
            raise ValueError(f"step_m must be > 0, got {step_m}")
        self.model, self.tol, self.step_m = model, tol, step_m
        self.pole = elongated(model)
        self.goal: tuple | None = None
        self.holds: dict = {}  # posture -> some grasp of it holds the object at the goal
        self.lone_holds: dict = {}  # (posture, place) -> ... with the lone finger no lower

    def __call__(self, contacts: Contacts, goal: np.ndarray) -> np.ndarray:
        key = tuple(np.round(goal, 9))
        if key != self.goal:
            self.goal, self.holds, self.lone_holds = key, {}, {}
        posture = contacts.posture
        if posture not in self.holds:
            self.holds[posture] = holds_near(self.model, posture, goal, self.tol)
        flip = not self.holds[posture]
        lone = False
        if self.pole and not flip and len(set(posture.faces)) == 2:  # both faces touched
            coord = contacts.coords[lone_finger(posture)]
            place = round(coord / self.step_m)
            if (posture, place) not in self.lone_holds:
                self.lone_holds[posture, place] = holds_near(
                    self.model, posture, goal, self.tol, lone_min=coord - LONE_SLACK_M)
            lone = not self.lone_holds[posture, place]
        return np.array([float(flip), float(lone)])
