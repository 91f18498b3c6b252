"""Fixtures for the primitive tests: the nominal hand model and fresh simulated worlds."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np
import pytest

from inhand_exp.config import HandConfig, ObjectConfig, PerturbConfig, SimConfig
from inhand_exp.control.grasp import Contacts
from inhand_exp.control.hand import HandModel
from inhand_exp.sim.world import ObjectSpec, World

PRESS_M = 0.0005  # how far the tips start pressed into the object's surface


@pytest.fixture(scope="module")
def nominal_model() -> HandModel:
    """The controller's model of the hand and of the nominal pole."""
    return HandModel.from_config(HandConfig(), ObjectConfig(), SimConfig().gravity_mps2)


@pytest.fixture
def make_world(nominal_model: HandModel) -> Iterator[Callable[..., World]]:
    """make_world(contacts, pose, perturb=None, q_model=None) -> a fresh World, reset.

    The object starts at ``pose`` and the fingers at ``q_model.grasp_q(contacts, pose,
    PRESS_M)`` (default ``q_model``: the nominal model); ``perturb`` scales the simulated object
    only. Every world made is closed at teardown.
    """
    worlds: list[World] = []

    def _make(contacts: Contacts, pose: np.ndarray, perturb: PerturbConfig | None = None,
              q_model: HandModel | None = None) -> World:
        world = World(SimConfig(), HandConfig(), ObjectSpec.from_config(ObjectConfig(), perturb))
        worlds.append(world)
        world.reset(pose, (q_model or nominal_model).grasp_q(contacts, pose, press=PRESS_M))
        return world

    yield _make
    for world in worlds:
        world.close()
