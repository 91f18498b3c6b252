"""Success, rewards and the paper's "useful flip" (section IV-A), from the simulated state.

The tolerances and rewards are the ``task`` config (``config.TaskConfig``).
"""

from __future__ import annotations

import math

import numpy as np

from inhand_exp.config import TaskConfig
from inhand_exp.control.grasp import Contacts, contact_frames, cross2
from inhand_exp.control.hand import HandModel


def pose_error(pose: np.ndarray, goal: np.ndarray) -> tuple[float, float, float]:
    """|dx|, |dz| (m) and |dtheta| (rad, wrapped) between two poses."""
    dth = (float(goal[2]) - float(pose[2]) + math.pi) % (2 * math.pi) - math.pi
    return abs(float(goal[0]) - float(pose[0])), abs(float(goal[1]) - float(pose[1])), abs(dth)


def reached(pose: np.ndarray, goal: np.ndarray, rules: TaskConfig) -> bool:
    """Success: |dx|, |dz| < tol_m and |dtheta| < tol_rad (paper: 1 cm, 0.1 rad)."""
    ex, ez, eth = pose_error(pose, goal)
    return ex < rules.success_tol_m and ez < rules.success_tol_m and eth < rules.success_tol_rad


def flip_useful(model: HandModel, contacts: Contacts, finger: int, pose: np.ndarray,
                goal: np.ndarray) -> bool:
    """After a flip: the flipped finger pushes so as to turn the object towards the goal angle.

    The paper calls a flip useful when the flipped finger's normal is aligned with the
    direction of ``theta_g - theta_t``; we read that as the torque of a push along the finger's
    inward normal, about the object's centre of mass, having the sign of the angle still to go.
    """
    pts, nrm = contact_frames(model.shape, contacts, pose)
    torque = cross2(pts[finger] - pose[:2], nrm[finger])
    to_go = (float(goal[2]) - float(pose[2]) + math.pi) % (2 * math.pi) - math.pi
    return torque * to_go > 0


def to_go(pose: np.ndarray, goal: np.ndarray, rules: TaskConfig) -> float:
    """Distance to the goal in tolerances: |dx|/tol_m + |dz|/tol_m + |dtheta|/tol_rad."""
    ex, ez, eth = pose_error(pose, goal)
    return (ex + ez) / rules.success_tol_m + eth / rules.success_tol_rad


def reward(rules: TaskConfig, *, valid: bool, success: bool, useful_flip: bool,
           progress: float = 0.0, route: float = 0.0) -> float:
    """The paper's reward: +5 goal, -0.01 invalid action, +1 useful successful flip.

    ``progress``: how much closer the action brought the object, ``to_go`` before minus after
    (simulated poses); it pays ``reward_progress`` each, a potential-based shaping (Ng et al.
    1999) that leaves the best policy unchanged and is off by default. ``route``: the seconds
    of the search graph's route to the goal the action saved (``route.RouteTime``), paid
    ``reward_route`` each, the same kind of shaping, also off by default.
    """
    r = rules.reward_progress * progress + rules.reward_route * route
    if not valid:
        r += rules.reward_invalid
    if useful_flip:
        r += rules.reward_flip
    if success:
        r += rules.reward_goal
    return r
