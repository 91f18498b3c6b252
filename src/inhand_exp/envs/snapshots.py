"""Snapshots of the simulated state during an action, for the ``/sim/state`` replay topic.

``Snapshots`` stands in for the world when a primitive is executed: it passes every call through
and, every ``every`` physics steps, records one row (time, object pose, joints, fingertip
contacts). The rows of one action travel as a fixed-size float tensor padded with NaN rows, so
they cross ``ParallelEnv``'s shared memory; ``rows_to_messages`` turns them back into messages.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

N_FINGERS = 3
CONTACT_WIDTH = 4  # x, z, normal force, tangential force (NaN: no contact)
STATE_WIDTH = 1 + 3 + 6 + 6 + N_FINGERS * CONTACT_WIDTH


class Snapshots:
    """A world that records a snapshot every ``every`` physics steps (episode time)."""

    def __init__(self, world, hz: float, longest_action_s: float):
        self.world = world
        self.every = max(1, round(1.0 / (hz * world.dt)))
        self.capacity = math.ceil(longest_action_s / (self.every * world.dt)) + 2
        self.steps, self.rows = 0, []

    def __getattr__(self, name: str) -> Any:  # everything else is the world's
        return getattr(self.world, name)

    def new_episode(self) -> None:
        self.steps = 0
        self.rows = [self.row()]

    def new_action(self) -> None:
        self.rows = []

    def step(self, tau: np.ndarray) -> None:
        self.world.step(tau)
        self.steps += 1
        if self.steps % self.every == 0 and len(self.rows) < self.capacity:
            self.rows.append(self.row())

    def row(self) -> np.ndarray:
        pose, _ = self.world.object_state()
        q, qd = self.world.joint_state()
        fingers = np.full((N_FINGERS, CONTACT_WIDTH), np.nan)
        for c in self.world.contacts():
            fingers[c.finger] = (*c.position, c.normal_force, c.tangential_force)
        return np.concatenate([[self.steps * self.world.dt], pose, q, qd, fingers.ravel()])

    def table(self) -> np.ndarray:
        """The rows since the last ``new_action``/``new_episode``, NaN-padded to ``capacity``."""
        out = np.full((self.capacity, STATE_WIDTH), np.nan, dtype=np.float32)
        if self.rows:
            out[:len(self.rows)] = np.asarray(self.rows)  # step() keeps to capacity
        return out


def rows_to_messages(rows: np.ndarray, episode: int) -> list[dict]:
    """``/sim/state`` messages from one NaN-padded table (padding rows skipped)."""
    out = []
    for r in np.asarray(rows, dtype=float):
        if math.isnan(r[0]):
            continue
        contacts = []
        for f in range(N_FINGERS):
            x, z, fn, ft = r[16 + CONTACT_WIDTH * f:16 + CONTACT_WIDTH * (f + 1)]
            if not math.isnan(x):
                contacts.append({"finger": f, "position": [float(x), float(z)],
                                 "normal_force_n": float(fn), "tangential_force_n": float(ft)})
        out.append({"episode": episode, "sim_time_s": float(r[0]),
                    "object_pose": [float(v) for v in r[1:4]],
                    "joint_q": [float(v) for v in r[4:10]],
                    "joint_qd": [float(v) for v in r[10:16]], "contacts": contacts})
    return out
