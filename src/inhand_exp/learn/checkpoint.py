"""Reading and writing a learner's ``policy.pt``: atomic writes, and reads that refuse anything
that is not one of ours with one clear ``CheckpointError`` (a text file, truncated or random
bytes, another learner's checkpoint, networks of other sizes)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import torch

from inhand_exp.errors import CheckpointError

REQUIRED = ("learner", "iteration", "frames")
TRAINED_WITH = "trained_with"  # the overrides of the training run(s) that made the policy


def save_checkpoint(state: dict, path: Path) -> None:
    """Write ``state`` atomically: a killed save never leaves a half-written checkpoint."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(state, tmp)
    tmp.replace(path)


def stamped(state: dict, overrides: list[str] | None) -> dict:
    """``state`` with the overrides of the training that made it (none recorded: unchanged), so
    that an evaluation of the file, wherever it is copied, knows the policy's recipe."""
    return state if overrides is None else {**state, TRAINED_WITH: list(overrides)}


def trained_with(state: dict) -> list[str] | None:
    """The training overrides ``stamped`` recorded in ``state``; None for a checkpoint written
    before they were recorded."""
    saved = state.get(TRAINED_WITH)
    return None if saved is None else [str(o) for o in saved]


def read_checkpoint(path: Path, learner: str) -> dict:
    """The state saved in ``path`` by ``learner``, or a ``CheckpointError`` saying why not.

    Loaded with ``weights_only=True``: a checkpoint is plain tensors and numbers, and nothing in
    the file is executed. Checkpoints written before the learner was recorded are PPO's.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint {path} not found")
    try:
        state = torch.load(path, weights_only=True)
    except Exception as err:  # noqa: BLE001 - any parse failure of a foreign file is refused
        raise CheckpointError(f"checkpoint {path} is not a policy.pt written by inhand-exp "
                              f"({type(err).__name__})") from None
    if not isinstance(state, dict) or not {"iteration", "frames"} <= state.keys():
        raise CheckpointError(f"checkpoint {path} is not a policy.pt written by inhand-exp "
                              f"(no training counters in it)")
    saved = state.get("learner", "ppo")
    if saved != learner:
        raise CheckpointError(f"checkpoint {path} was trained by learner={saved}; this "
                              f"configuration has learner={learner}")
    return state


def restore(path: Path, load: Callable[[], None]) -> None:
    """Run ``load`` (the ``load_state_dict`` calls), turning a shape or key mismatch into a
    ``CheckpointError``."""
    try:
        load()
    except (RuntimeError, KeyError, ValueError, TypeError) as err:
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise CheckpointError(f"checkpoint {path} does not fit this configuration: "
                              f"{first}") from None
