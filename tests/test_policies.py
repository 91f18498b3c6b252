"""The packaged policies: ``checkpoint=packaged:NAME`` names one, a wrong name is refused."""

from __future__ import annotations

import pytest

from inhand_exp import policies
from inhand_exp.config import ConfigError
from inhand_exp.learn.checkpoint import read_checkpoint


def test_every_packaged_policy_resolves_to_an_actor_that_records_its_recipe():
    assert policies.DEMO in policies.names()
    for name in policies.names():
        path = policies.resolve(f"packaged:{name}")
        state = read_checkpoint(path, "ppo")
        assert "actor" in state and "critic" not in state and "optim" not in state
        assert any(o.startswith("train.frames=") for o in state["trained_with"]), name
        assert state["frames"] > 0


def test_a_plain_path_or_none_passes_unchanged(tmp_path):
    assert policies.resolve(None) is None
    assert policies.resolve(str(tmp_path / "policy.pt")) == str(tmp_path / "policy.pt")


def test_an_unknown_name_is_refused_naming_the_packaged_ones():
    with pytest.raises(ConfigError, match="no packaged policy 'table9'.*packaged:table2_ppo_seed0"):
        policies.resolve("packaged:table9")
