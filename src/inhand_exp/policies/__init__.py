"""The policies packaged with inhand-exp (``README.md`` here says how each was trained).

``checkpoint=packaged:NAME`` names one on the command line, ``NAME`` being its file name without
``.pt``: ``inhand-exp checkpoint=packaged:table2_clone_seed0 task.no_undo=true`` shows the clone
of the search's demonstrations as ``inhand-exp`` alone shows the Table II policy.
"""

from __future__ import annotations

import importlib.resources
from pathlib import Path

from inhand_exp.config import ConfigError

PREFIX = "packaged:"
DEMO = "table2_ppo_seed0"  # what mode=demo shows without a checkpoint


def packaged(name: str) -> Path:
    """The file of the packaged policy ``name`` (which may not exist)."""
    return Path(str(importlib.resources.files(__name__).joinpath(f"{name}.pt")))


def names() -> list[str]:
    """The packaged policies, by name."""
    return sorted(p.name[:-3] for p in importlib.resources.files(__name__).iterdir()
                  if p.name.endswith(".pt"))


def resolve(checkpoint: str | None) -> str | None:
    """``checkpoint`` with ``packaged:NAME`` turned into that policy's path; any other value
    as given. An unknown name is refused, naming the packaged ones."""
    if not checkpoint or not str(checkpoint).startswith(PREFIX):
        return checkpoint
    name = str(checkpoint)[len(PREFIX):].removesuffix(".pt")
    path = packaged(name)
    if not path.is_file():
        raise ConfigError(f"checkpoint={checkpoint}: no packaged policy {name!r}; the packaged "
                          f"ones: {', '.join(PREFIX + n for n in names())}")
    return str(path)
