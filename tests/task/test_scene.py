"""The scene builder: one nominal model for the controllers, the perturbed object simulated."""

from __future__ import annotations

import numpy as np
import pytest
from omegaconf import OmegaConf

from inhand_exp.config import PrimitivesConfig, TaskConfig
from inhand_exp.task.scene import build_scene


def test_perturbation_reaches_the_simulator_and_not_the_controllers(compose_cfg):
    cfg = compose_cfg("perturb=heavier", "noise=paper")
    scene = build_scene(cfg)
    try:
        nominal, simulated = scene.model.shape, scene.true_model.shape
        assert nominal.mass_kg == pytest.approx(cfg.object.mass_kg)
        assert simulated.mass_kg == pytest.approx(cfg.object.mass_kg * cfg.perturb.mass_scale)
        assert scene.world.obj.mass_kg == pytest.approx(simulated.mass_kg)
        assert simulated.mass_kg != nominal.mass_kg
        np.testing.assert_allclose(scene.noise, [cfg.noise.xz_m, cfg.noise.xz_m,
                                                 cfg.noise.theta_rad])
    finally:
        scene.close()


def test_a_worker_s_plain_dict_builds_the_same_typed_scene(compose_cfg):
    """Worker processes get the config as a plain dict; the scene must not depend on it."""
    cfg = compose_cfg("primitives.kp=123", "task.filter=penalty", "task.reward_progress=0.1")
    plain = OmegaConf.to_container(cfg, resolve=True, enum_to_str=True)
    a, b = build_scene(cfg), build_scene(plain)
    try:
        for s in (a, b):
            assert isinstance(s.prim, PrimitivesConfig) and isinstance(s.rules, TaskConfig)
        assert a.prim == b.prim and a.rules == b.rules
        assert (b.prim.kp, str(b.rules.filter), b.rules.reward_progress) == (
            123.0, "penalty", 0.1)
    finally:
        a.close()
        b.close()


def test_observation_noise_is_drawn_per_call_and_bounded(compose_cfg):
    scene = build_scene(compose_cfg("noise=paper"))
    try:
        scene.world.reset(np.array([0.0, 0.34, 0.0]), np.zeros(6))
        rng = np.random.default_rng(0)
        offsets = np.array([scene.observe(rng)[1] for _ in range(50)])
        assert np.all(np.abs(offsets) <= scene.noise) and offsets.std(0).min() > 0
        obs, offset, true = scene.observe(rng)
        np.testing.assert_allclose(obs.pose, true + offset)
    finally:
        scene.close()
