"""The networks' view of the observation: unit scales and the wrapped goal error."""

from __future__ import annotations

import math

import pytest
import torch

from inhand_exp.learn.features import ObservationFeatures


def test_goal_error_is_appended_and_the_angle_wrapped():
    from inhand_exp.control.sample import Workspace

    ws = Workspace()
    centre = [(lo + hi) / 2 for lo, hi in zip(ws.low, ws.high, strict=True)]
    x, z, _ = centre
    obs = torch.zeros(2, 18)
    obs[:, 12:15] = torch.tensor([[x + 0.01, z, math.pi - 0.05], centre])
    obs[:, 15:18] = torch.tensor([[x + 0.03, z - 0.02, -math.pi + 0.05], [x, z, 0.1]])
    out = ObservationFeatures()(obs)
    assert out.shape == (2, 21)
    torch.testing.assert_close(out[:, 18:], torch.tensor([[1.0, -1.0, 0.5], [0.0, 0.0, 0.5]]))
    assert out[1, 12:15].abs().max() < 1e-6  # the centre of the sampling workspace maps to 0


def test_extras_pass_through_and_short_observations_are_refused():
    obs = torch.zeros(20)
    obs[18:] = torch.tensor([3.0, -4.0])
    out = ObservationFeatures(20)(obs)
    assert out.shape == (23,) and out[18:20].tolist() == [3.0, -4.0]
    with pytest.raises(ValueError, match="need 18"):
        ObservationFeatures(12)


def test_fingertips_on_the_object_match_the_controllers_kinematics(compose_cfg):
    """Forward kinematics in torch equals the controller's object-frame tips ``R^T (tip - p)``
    on sampled grasps: the O_x offset across the upright pole tells the side (a tip radius
    outside LEFT or RIGHT) and the O_z component is the contact coordinate along it."""
    import numpy as np

    from inhand_exp.control.grasp import Face, rotation
    from inhand_exp.control.hand import HandModel
    from inhand_exp.control.sample import random_grasp
    from inhand_exp.learn.features import HandGeometry

    cfg = compose_cfg()
    model = HandModel.from_config(cfg.hand, cfg.object, cfg.sim.gravity_mps2)
    features = ObservationFeatures(18, HandGeometry.from_config(cfg.hand), n_actions=14)
    rng = np.random.default_rng(0)
    for _ in range(10):
        pose, contacts, q = random_grasp(model, rng, press=0.0)
        obs = torch.zeros(18, dtype=torch.float64)
        obs[:6], obs[12:15] = torch.from_numpy(q), torch.from_numpy(pose)
        tips = features.double().tips_in_object(obs).numpy()
        expected = (model.tips(q) - pose[:2]) @ rotation(pose[2])  # rows: R^T (tip - p)
        # the geometry buffers are built in single precision: 0.16 m is off by ~4e-9 m
        np.testing.assert_allclose(tips, expected, rtol=0, atol=1e-7)
        assert set(contacts.posture.faces) <= {Face.LEFT, Face.RIGHT}
        np.testing.assert_allclose(tips[:, 1], contacts.coords, rtol=0, atol=1e-7)  # along O_z
        side = cfg.object.width_m / 2 + cfg.hand.tip_radius_m
        across = [side if f == Face.RIGHT else -side for f in contacts.posture.faces]
        np.testing.assert_allclose(tips[:, 0], across, rtol=0, atol=1e-7)  # across, O_x
    out = features.float()(obs.float(), torch.ones(14, dtype=torch.bool))
    assert out.shape == (features.out_features,) == (18 + 3 + 6 + 14,)
    with pytest.raises(ValueError, match="action mask"):
        features(obs.float())
