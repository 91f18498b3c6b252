"""Demonstrations: another policy's episodes, recorded to warm-start PPO by behaviour cloning.

The graph search finds routes that PPO's exploration seldom does (lift the pole, then flip), and
PPO solves the pairs the search's lattice misses. An evaluation with ``eval.demonstrations=true``
records, for every mid-level action, the observation and mask the policy saw and the action it
took, with each episode's outcome, in ``demonstrations.pt`` beside its log; with
``eval.split=train`` it plays the group's training pairs, so that no test pair is seen.

PPO with ``learner.demonstrations=[FILE, ...]`` reads the steps of the successful episodes.
Before its first iteration it fits the actor to them (``learner.bc_epochs`` passes of
cross-entropy over the mask, as in behaviour cloning); while it trains, a cloning term weighted
``learner.bc_coef``, falling linearly to zero over ``learner.bc_frames`` frames, keeps it from
forgetting them while the critic learns (Rajeswaran et al. 2018, "DAPG", in its simplest form).
Files hold plain tensors and numbers and load with ``torch.load(weights_only=True)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch
from tensordict import TensorDict

from inhand_exp.errors import DemonstrationsError
from inhand_exp.learn.checkpoint import save_checkpoint

FORMAT = "inhand-exp demonstrations 1"


class DemoRecorder:
    """Collects each step's (observation, mask, action) by episode, and each episode's
    outcome; ``save`` writes them."""

    def __init__(self):
        self.obs: list[torch.Tensor] = []
        self.mask: list[torch.Tensor] = []
        self.action: list[int] = []
        self.episode: list[int] = []
        self.outcome: dict[int, tuple[bool, str]] = {}

    def step(self, episode: int, row) -> None:
        """One action of ``episode``: ``row`` is the policy's tensordict row (before the step)."""
        self.obs.append(row["observation"].detach().float().clone())
        self.mask.append(row["action_mask"].detach().bool().clone())
        self.action.append(int(row["action"]))
        self.episode.append(episode)

    def end(self, record: dict) -> None:
        """The ``/eval/episode`` record of a finished episode."""
        self.outcome[int(record["episode"])] = (bool(record["success"]), str(record["group"]))

    def save(self, path: Path, meta: dict) -> Path:
        if not self.obs:
            raise DemonstrationsError("no step was recorded; nothing to save")
        episodes = sorted(self.outcome)
        state = {"format": FORMAT,
                 "observation": torch.stack(self.obs), "action_mask": torch.stack(self.mask),
                 "action": torch.tensor(self.action, dtype=torch.long),
                 "episode": torch.tensor(self.episode, dtype=torch.long),
                 "episodes": torch.tensor(episodes, dtype=torch.long),
                 "success": torch.tensor([self.outcome[e][0] for e in episodes]),
                 "groups": [self.outcome[e][1] for e in episodes], **meta}
        save_checkpoint(state, Path(path))
        return Path(path)


def read_demonstrations(path: str | Path) -> dict:
    """The contents of one demonstrations file, or a ``DemonstrationsError`` saying why not."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"demonstrations {path} not found (record them with an "
                                f"evaluation run and eval.demonstrations=true)")
    try:
        state = torch.load(path, weights_only=True)
    except Exception as err:  # noqa: BLE001 - any parse failure of a foreign file is refused
        raise DemonstrationsError(f"demonstrations {path} is not a file written by inhand-exp "
                                  f"({type(err).__name__})") from None
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise DemonstrationsError(f"demonstrations {path} is not a file written by inhand-exp "
                                  f"(expected the format '{FORMAT}')")
    return state


def load_demonstrations(paths: Sequence[str | Path], obs_dim: int, n_actions: int
                        ) -> TensorDict:
    """The steps of the successful episodes of every file in ``paths``, as one flat batch
    (``observation``, ``action_mask``, ``action``). A file recorded with another observation
    or action size (``task.route_advice``, ``task.posture_advice``, another primitive set) is
    refused, naming it; so is a set with no successful episode."""
    parts = []
    for path in paths:
        state = read_demonstrations(path)
        obs, mask = state["observation"], state["action_mask"]
        if obs.shape[-1] != obs_dim or mask.shape[-1] != n_actions:
            raise DemonstrationsError(
                f"demonstrations {path} were recorded with {obs.shape[-1]} observations and "
                f"{mask.shape[-1]} actions; this configuration has {obs_dim} and {n_actions} "
                f"(record them with the same task.route_advice, task.posture_advice and "
                f"primitives)")
        won = state["episodes"][state["success"]]
        keep = torch.isin(state["episode"], won)
        parts.append(TensorDict({"observation": obs[keep], "action_mask": mask[keep],
                                 "action": state["action"][keep]}, batch_size=[int(keep.sum())]))
    data = torch.cat(parts) if parts else None
    if data is None or len(data) == 0:
        raise DemonstrationsError(f"demonstrations {', '.join(map(str, paths))} hold no step of "
                                  f"a successful episode")
    return data


def cloning_loss(actor, batch: TensorDict) -> torch.Tensor:
    """Mean negative log-likelihood of the demonstrated actions under ``actor``'s masked
    distribution (the action is allowed by its own recorded mask)."""
    dist = actor.get_dist(batch.select("observation", "action_mask"))
    return -dist.log_prob(batch["action"]).mean()


def clone(actor, data: TensorDict, epochs: int, minibatch: int, optim: torch.optim.Optimizer,
          max_grad_norm: float) -> float:
    """Fit ``actor`` to ``data`` for ``epochs`` passes; the last pass's mean loss."""
    mean = float("nan")
    for _ in range(epochs):
        losses = []
        for idx in torch.randperm(len(data)).split(minibatch):
            loss = cloning_loss(actor, data[idx])
            optim.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(actor.parameters(), max_grad_norm)
            optim.step()
            losses.append(float(loss.detach()))
        mean = sum(losses) / len(losses)
    return mean
