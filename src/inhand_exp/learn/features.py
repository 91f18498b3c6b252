"""What the networks make of the paper's observation before their first layer.

A fixed affine normaliser brings joint angles, velocities and poses to unit scale, and the goal
error ``X_g - X_t`` (angle wrapped) is appended, since every action is judged by how it changes
that error. Both are functions of the observation alone; the scales are buffers, saved with the
networks. Floats past the paper's 18 (extras) pass through unscaled.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from inhand_exp.envs.specs import OBS_DIM

POSE_CENTER = (0.0, 0.2, 0.0)  # the middle of the workspace (m, m, rad)
POSE_SCALE = (0.05, 0.05, 0.5)
ERROR_SCALE = (0.02, 0.02, 0.2)  # two repose steps


class ObservationFeatures(nn.Module):
    """(..., n) observation -> (..., n + 3): normalised q, qd, X_t, X_g, extras, goal error."""

    def __init__(self, obs_dim: int = OBS_DIM):
        super().__init__()
        if obs_dim < OBS_DIM:
            raise ValueError(f"the observation has {obs_dim} floats; q, qd, X_t and X_g "
                             f"need {OBS_DIM}")
        extra = obs_dim - OBS_DIM
        center = [0.0] * 12 + [*POSE_CENTER] * 2 + [0.0] * extra
        scale = [1.0] * 6 + [5.0] * 6 + [*POSE_SCALE] * 2 + [1.0] * extra
        self.out_features = obs_dim + 3
        self.register_buffer("center", torch.tensor(center))
        self.register_buffer("scale", torch.tensor(scale))
        self.register_buffer("error_scale", torch.tensor(ERROR_SCALE))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        error = obs[..., 15:18] - obs[..., 12:15]
        angle = torch.remainder(error[..., 2:] + math.pi, 2 * math.pi) - math.pi
        error = torch.cat([error[..., :2], angle], dim=-1)
        return torch.cat([(obs - self.center) / self.scale, error / self.error_scale], dim=-1)
