"""Grasp sampling: the vectorised reach of a face gives the scalar reference's answers."""

from __future__ import annotations

import numpy as np
import pytest

from inhand_exp.config import HandConfig, ObjectConfig
from inhand_exp.control import sample
from inhand_exp.control.grasp import Face
from inhand_exp.control.hand import HandModel


@pytest.fixture(scope="module")
def model() -> HandModel:
    return HandModel.from_config(HandConfig(), ObjectConfig(), 9.81)


def reference(model, finger, face, pose, step_m=0.005, margin=0.1):
    r = model.tip_radius
    n = int((model.shape.half_extent(face) - 2 * r) // step_m)
    return [k * step_m for k in range(-n, n + 1)
            if sample._touches(model, finger, face, pose, k * step_m, margin)]


@pytest.mark.parametrize("guard", [sample.GUARD, 0.02])
def test_face_coords_equal_the_scalar_reference(model, guard, monkeypatch):
    """Over random poses in and beyond the workspace, every finger and long face: the same
    coordinates as the plain-float loop. A wide guard band sends many coordinates to the
    scalar fallback, which must give the same answers too."""
    monkeypatch.setattr(sample, "GUARD", guard)
    rng = np.random.default_rng(4)
    held = 0
    for _ in range(60):
        pose = rng.uniform([-0.08, 0.1, -1.8], [0.08, 0.6, 1.8])
        for i in range(3):
            for face in (Face.LEFT, Face.RIGHT):
                want = reference(model, i, face, pose)
                assert sample.face_coords(model, i, face, pose) == want
                held += bool(want)
    assert 40 < held < 300  # both kinds of answer are exercised
