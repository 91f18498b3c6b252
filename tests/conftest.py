"""Shared fixtures: composing the project's Hydra config without running the app."""

from __future__ import annotations

from collections.abc import Callable

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import DictConfig

from inhand_exp.cli import CONF_DIR


@pytest.fixture
def compose_cfg() -> Callable[..., DictConfig]:
    """compose_cfg("object=cube", ...) -> the composed config, as the app would see it."""

    def _compose(*overrides: str) -> DictConfig:
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
            return compose(config_name="config", overrides=list(overrides))

    return _compose
