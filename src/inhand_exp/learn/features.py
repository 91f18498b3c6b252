"""What the networks make of the observation before their first layer.

A fixed affine normaliser brings joint angles, velocities and poses to unit scale, and the goal
error ``X_g - X_t`` (angle wrapped) is appended, since every action is judged by how it changes
that error. Floats past the paper's 18 (extras) pass through unscaled.

With a ``HandGeometry`` the features also place each fingertip on the object: forward kinematics
of ``q`` in the frame of ``X_t`` gives, per finger, its offset across the object's long axis
(which side it is on) and its coordinate along it. Which grasp holds the object decides which
primitives can move it where, and an MLP would otherwise have to learn the kinematics from
joint angles. With ``n_actions`` the feasibility mask is appended too. All of these are
functions of what the environment returns; the scales and the geometry are buffers, saved with
the networks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from inhand_exp.envs.specs import OBS_DIM

POSE_CENTER = (0.0, 0.35, 0.0)  # the middle of the workspace (m, m, rad)
POSE_SCALE = (0.05, 0.1, 1.0)
ERROR_SCALE = (0.02, 0.02, 0.2)  # two repose steps
TIP_SCALE = (0.02, 0.25)  # across (a tip outside a long side) and along (half a pole), m


@dataclass(frozen=True)
class HandGeometry:
    """Finger base positions and link lengths (m): what forward kinematics needs."""

    base_x: tuple[float, float, float]
    base_z: float
    l1: float
    l2: float

    @classmethod
    def from_config(cls, hand) -> HandGeometry:
        l1, l2 = hand.link_lengths_m
        return cls(tuple(hand.finger_base_x_m), hand.base_z_m, l1, l2)


class ObservationFeatures(nn.Module):
    """(..., n) observation [and (..., a) mask] -> (..., out_features) network input."""

    def __init__(self, obs_dim: int = OBS_DIM, hand: HandGeometry | None = None,
                 n_actions: int = 0):
        super().__init__()
        if obs_dim < OBS_DIM:
            raise ValueError(f"the observation has {obs_dim} floats; q, qd, X_t and X_g "
                             f"need {OBS_DIM}")
        extra = obs_dim - OBS_DIM
        center = [0.0] * 12 + [*POSE_CENTER] * 2 + [0.0] * extra
        scale = [1.0] * 6 + [5.0] * 6 + [*POSE_SCALE] * 2 + [1.0] * extra
        self.kinematic = hand is not None
        self.n_actions = n_actions
        self.out_features = obs_dim + 3 + (6 if self.kinematic else 0) + n_actions
        self.register_buffer("center", torch.tensor(center))
        self.register_buffer("scale", torch.tensor(scale))
        self.register_buffer("error_scale", torch.tensor(ERROR_SCALE))
        if hand is not None:
            self.register_buffer("bases", torch.tensor([[x, hand.base_z] for x in hand.base_x]))
            self.register_buffer("links", torch.tensor([hand.l1, hand.l2]))
            self.register_buffer("tip_scale", torch.tensor(TIP_SCALE))

    def tips_in_object(self, obs: torch.Tensor) -> torch.Tensor:
        """(..., 3, 2): each fingertip centre in the object frame of ``X_t`` (m)."""
        q = obs[..., :6].unflatten(-1, (3, 2))
        q1, q12 = q[..., 0], q[..., 0] + q[..., 1]
        l1, l2 = self.links[0], self.links[1]
        tips = self.bases + torch.stack([l1 * torch.cos(q1) + l2 * torch.cos(q12),
                                         l1 * torch.sin(q1) + l2 * torch.sin(q12)], dim=-1)
        rel = tips - obs[..., None, 12:14]
        c, s = torch.cos(obs[..., 14:15]), torch.sin(obs[..., 14:15])
        return torch.stack([c * rel[..., 0] + s * rel[..., 1],
                            -s * rel[..., 0] + c * rel[..., 1]], dim=-1)  # R^T rel

    def forward(self, obs: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        error = obs[..., 15:18] - obs[..., 12:15]
        angle = torch.remainder(error[..., 2:] + math.pi, 2 * math.pi) - math.pi
        error = torch.cat([error[..., :2], angle], dim=-1)
        parts = [(obs - self.center) / self.scale, error / self.error_scale]
        if self.kinematic:
            parts.append((self.tips_in_object(obs) / self.tip_scale).flatten(-2))
        if self.n_actions:
            if mask is None:
                raise ValueError("these features include the action mask; none was given")
            parts.append(mask.to(obs.dtype))
        return torch.cat(parts, dim=-1)
