"""The networks' view of the observation: unit scales and the wrapped goal error."""

from __future__ import annotations

import math

import pytest
import torch

from inhand_exp.learn.features import ObservationFeatures


def test_goal_error_is_appended_and_the_angle_wrapped():
    obs = torch.zeros(2, 18)
    obs[:, 12:15] = torch.tensor([[0.01, 0.2, math.pi - 0.05], [0.0, 0.2, 0.0]])
    obs[:, 15:18] = torch.tensor([[0.03, 0.18, -math.pi + 0.05], [0.0, 0.2, 0.1]])
    out = ObservationFeatures()(obs)
    assert out.shape == (2, 21)
    torch.testing.assert_close(out[:, 18:], torch.tensor([[1.0, -1.0, 0.5], [0.0, 0.0, 0.5]]))
    assert out[1, 12:15].abs().max() < 1e-6  # the workspace centre maps to 0


def test_extras_pass_through_and_short_observations_are_refused():
    obs = torch.zeros(20)
    obs[18:] = torch.tensor([3.0, -4.0])
    out = ObservationFeatures(20)(obs)
    assert out.shape == (23,) and out[18:20].tolist() == [3.0, -4.0]
    with pytest.raises(ValueError, match="need 18"):
        ObservationFeatures(12)
