"""Every config option composes; typos, wrong types and impossible values fail naming the key."""

from __future__ import annotations

import dataclasses
import re

import pytest
from hydra.errors import ConfigCompositionException
from omegaconf import OmegaConf

from inhand_exp.cli import CONF_DIR
from inhand_exp.config import GROUP_SCHEMAS, LEARNER_SCHEMAS, Config, ConfigError, validate

SWEEP_GROUPS = ("profile", "recipe")  # selected with +group=option by the sweeps
GROUPS = sorted(p.name for p in CONF_DIR.iterdir() if p.is_dir() and p.name not in SWEEP_GROUPS)


def options(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml"))


def test_every_group_has_options_and_a_schema():
    assert set(GROUPS) == set(GROUP_SCHEMAS) | {"learner"}
    assert options("perturb") == sorted(
        ["none", "heavier", "lighter", "thicker", "thinner", "longer", "shorter"])
    assert options("learner") == sorted(LEARNER_SCHEMAS)


@pytest.mark.parametrize(("group", "option"),
                         [(g, o) for g in GROUPS for o in options(g)])
def test_every_option_composes_and_validates(compose_cfg, group, option):
    extra = [f"object={option}"] if group == "primitives" else []
    cfg = compose_cfg("mode=train_eval", f"{group}={option}", *extra)
    validate(cfg)
    assert OmegaConf.get_type(cfg[group]) is not dict  # typed by its schema
    if hasattr(cfg[group], "name"):
        assert cfg[group].name == option or group in ("sim", "hand")


@pytest.mark.parametrize(("group", "option"),
                         [(g, o) for g in SWEEP_GROUPS for o in options(g)])
def test_every_sweep_option_composes_and_validates(compose_cfg, group, option):
    cfg = compose_cfg("mode=train_eval", f"+{group}={option}")
    validate(cfg)
    if group == "recipe":
        assert cfg.learner.name == option


def test_the_default_mode_is_the_demo_and_refuses_other_learners(compose_cfg):
    assert str(compose_cfg().mode) == "demo"
    with pytest.raises(ConfigError, match="mode=demo shows the packaged PPO policy"):
        validate(compose_cfg("learner=ddpg"))


def test_defaults_are_the_paper_setting(compose_cfg):
    cfg = compose_cfg()
    assert (cfg.object.name, cfg.primitives.name, cfg.learner.name) == ("pole", "pole", "ppo")
    assert (cfg.perturb.name, cfg.noise.name) == ("none", "none")
    assert cfg.task.filter.value == "mask" and cfg.train.num_envs == 16
    assert cfg.eval.episodes == 100 and cfg.train.frames == 1024


def test_object_choice_selects_matching_primitives(compose_cfg):
    cfg = compose_cfg("object=cube")
    assert cfg.primitives.name == "cube" and not cfg.primitives.slide
    assert cfg.object.length_m == pytest.approx(0.10)


@pytest.mark.parametrize(("perturb", "field", "scale"), [
    ("heavier", "mass_scale", 1.1), ("lighter", "mass_scale", 0.9),
    ("thicker", "width_scale", 1.5), ("thinner", "width_scale", 0.5),
    ("longer", "length_scale", 1.1), ("shorter", "length_scale", 0.9)])
def test_perturbations_scale_one_property(compose_cfg, perturb, field, scale):
    p = compose_cfg(f"perturb={perturb}").perturb
    scales = {k: p[k] for k in ("mass_scale", "width_scale", "length_scale")}
    assert scales.pop(field) == pytest.approx(scale)
    assert scales == {k: 1.0 for k in scales}


def test_paper_noise(compose_cfg):
    n = compose_cfg("noise=paper").noise
    assert n.xz_m == pytest.approx(0.005)
    assert n.theta_rad == pytest.approx(2.86 * 3.141592653589793 / 180)


@pytest.mark.parametrize(("override", "key"), [
    ("object.mas_kg=1", "object.mas_kg"),
    ("learner.lrr=0.1", "learner.lrr"),
    ("sed=1", "sed"),
])
def test_typo_in_a_key_names_the_key(compose_cfg, override, key):
    with pytest.raises(ConfigCompositionException) as err:
        compose_cfg(override)
    assert f"Could not override '{key}'" in str(err.value)


def test_appended_unknown_key_is_rejected_by_validate(compose_cfg):
    cfg = compose_cfg("+object.colour=red")
    with pytest.raises(ConfigError, match="unknown key 'object.colour'"):
        validate(cfg)


@pytest.mark.parametrize(("override", "key"), [
    ("seed=abc", "seed"), ("object.mass_kg=heavy", "object.mass_kg"),
    ("mode=fly", "mode"), ("task.filter=maybe", "task.filter")])
def test_wrong_type_names_the_key(compose_cfg, override, key):
    with pytest.raises(ConfigCompositionException) as err:
        compose_cfg(override)
    assert f"Error merging override {override}" in str(err.value)
    assert key.split(".")[-1] in str(err.value.__cause__)


@pytest.mark.parametrize(("override", "message"), [
    ("object.mass_kg=0", "object.mass_kg must be > 0, got 0.0"),
    ("object.mass_kg=-0.1", "object.mass_kg must be > 0, got -0.1"),
    ("object.width_m=0", "object.width_m must be > 0, got 0.0"),
    ("object.length_m=-1", "object.length_m must be > 0, got -1.0"),
    ("object.friction=-0.2", "object.friction must be >= 0, got -0.2"),
    ("hand.friction=-1", "hand.friction must be >= 0, got -1.0"),
    ("perturb.mass_scale=0", "perturb.mass_scale must be > 0, got 0.0"),
    ("noise.xz_m=-0.01", "noise.xz_m must be >= 0, got -0.01"),
    ("noise.theta_rad=-1", "noise.theta_rad must be >= 0, got -1.0"),
    ("eval.episodes=0", "eval.episodes must be > 0, got 0"),
    ("sim.timestep_s=0", "sim.timestep_s must be > 0, got 0.0"),
    ("sim.timestep_s=-0.001", "sim.timestep_s must be > 0, got -0.001"),
    ("hand.link_lengths_m=[0.16,0]", "hand.link_lengths_m[1] must be > 0, got 0.0"),
    ("hand.finger_base_x_m=[0,1]", "hand.finger_base_x_m must have 3 entries, got 2"),
    ("object.mass_kg=nan", "object.mass_kg must be a finite number, got nan"),
    ("goals.hard_flip_share=1.5", "goals.hard_flip_share must be <= 1, got 1.5"),
    ("goals.hard_flip_share=-0.1", "goals.hard_flip_share must be >= 0, got -0.1"),
    ("goals.train_groups=[easy,hardest]",
     "goals.train_groups[1] must be one of ['easy', 'medium', 'hard', 'flip', 'lone'], got "
     "'hardest'"),
])
def test_impossible_values_name_field_and_value(compose_cfg, override, message):
    cfg = compose_cfg(override)
    with pytest.raises(ConfigError) as err:
        validate(cfg)
    assert message in str(err.value)


@pytest.mark.parametrize(("overrides", "message"), [
    (["object=cube", "primitives=pole"], "primitives=pole does not fit object=cube"),
    (["primitives.repose_duration_s=0.501"], "not a whole number of control periods"),
    (["mode=eval"], "mode=eval needs checkpoint=PATH"),
    (["object=cube", "learner=search", "mode=eval"],
     "learner=search plans over a pole's two long faces; it has no graph for object=cube"),
    (["object=cube", "goals.train_groups=[medium,lone]"],
     "'lone' (a pole's lone finger ending lower) has no pairs for object=cube"),
    (["learner.frames_per_batch=100"],
     "learner.frames_per_batch=100 must be a multiple of train.num_envs=16"),
    (["hand.joint_lower_rad=[1,0]", "hand.joint_upper_rad=[0,1]"],
     "hand.joint_lower_rad[0] < hand.joint_upper_rad[0]"),
])
def test_inconsistent_settings_are_rejected(compose_cfg, overrides, message):
    with pytest.raises(ConfigError, match=re.escape(message)):
        validate(compose_cfg(*overrides))


def test_every_schema_field_is_documented():
    schemas = [Config, *GROUP_SCHEMAS.values(), *LEARNER_SCHEMAS.values()]
    seen = set()
    while schemas:
        schema = schemas.pop()
        seen.add(schema)
        for f in dataclasses.fields(schema):
            if dataclasses.is_dataclass(f.type if isinstance(f.type, type) else None):
                schemas.append(f.type)
            if f.name in {"sim", "hand", "object", "perturb", "noise", "primitives", "goals",
                          "learner", "task", "train", "eval", "log"}:
                continue
            assert f.metadata.get("doc"), f"{schema.__name__}.{f.name} has no doc"
