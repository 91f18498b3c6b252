"""Evaluation (paper section IV): episodes on a fixed goal set, judged from the simulated state.

The environment is a batch of ``n`` primitive environments built on the same goal list (see
``envs.batched``): environment ``i`` plays goals ``i, i + n, i + 2n, ...``, so the episode number
is the goal's index and the results do not depend on how the batch runs. Each episode yields one
record (the ``/eval/episode`` fields), each action one ``/episode/action`` record and, when the
environment records them, the ``/sim/state`` snapshots; the summary has the success, drop and
timeout rates and the mean simulated time of the successful episodes. Given the indices of
the flipping actions (``task.actions.flip_actions``), an episode also counts its flips
(``n_flips``: flips, or the cube's lands, that ended ``done``), so that the pairs that need one
show how often the policy made one.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence
from typing import Any

import numpy as np
import torch
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from inhand_exp.envs.primitive_env import OUTCOMES
from inhand_exp.envs.snapshots import rows_to_messages
from inhand_exp.task.goals import GoalPair
from inhand_exp.task.rules import pose_error

Record = dict[str, Any]
Sink = Callable[[Record], None]
DONE = OUTCOMES.index("done")


def evaluate(env: EnvBase, policy, goals: Sequence[GoalPair],
             on_episode: Sink | None = None, on_action: Sink | None = None,
             on_state: Sink | None = None, action_names: Sequence[str] | None = None,
             sample: bool = False,
             flip_actions: Collection[int] | None = None,
             on_step: Callable[[int, Any], None] | None = None) -> dict[str, float]:
    """Play every pair of ``goals`` once with the policy's most likely actions (``sample``:
    actions drawn from it, with torch's global generator); summarise. ``flip_actions``: the
    indices whose finished runs each episode counts (``n_flips``); None: no count.
    ``on_step(episode, row)``: every action's tensordict row (what the policy saw and did).

    The batch runs in this process's policy call, so the draws do not depend on the backend.
    """
    n = max(1, env.batch_size.numel())
    need = np.array([len(goals[i::n]) for i in range(n)])
    played = np.zeros(n, dtype=int)  # finished episodes of each environment
    steps, invalid = np.zeros(n, dtype=int), np.zeros(n, dtype=int)
    flips = np.zeros(n, dtype=int)
    records: list[Record] = []
    mode = ExplorationType.RANDOM if sample else ExplorationType.DETERMINISTIC
    with set_exploration_type(mode), torch.no_grad():
        td = env.reset()
        _states(td, range(n), played, n, on_state)
        while (played < need).any():
            td = policy(td)
            td, root = env.step_and_maybe_reset(td)
            flat = td.reshape(-1)
            done = flat["next", "done"].reshape(n).tolist()
            for i in range(n):
                if played[i] >= need[i]:
                    continue
                ep = i + n * int(played[i])
                row = flat[i]
                if on_step is not None:
                    on_step(ep, row)
                if on_action is not None:
                    on_action(_action(row, ep, int(steps[i]), action_names))
                if on_state is not None and "states" in row["next"]:
                    for msg in rows_to_messages(row["next", "states"].numpy(), ep):
                        on_state(msg)
                steps[i] += 1
                invalid[i] += not bool(row["next", "valid"])
                if flip_actions is not None:
                    flips[i] += (int(row["action"]) in flip_actions
                                 and int(row["next", "outcome"]) == DONE)
                if done[i]:
                    rec = _episode(row["next"], goals[ep], ep, int(steps[i]), int(invalid[i]))
                    if flip_actions is not None:
                        rec["n_flips"] = int(flips[i])
                    records.append(rec)
                    if on_episode is not None:
                        on_episode(rec)
                    played[i] += 1
                    steps[i], invalid[i], flips[i] = 0, 0, 0
            _states(root, [i for i in range(n) if done[i]], played, n, on_state, need)
            td = root
    records.sort(key=lambda r: r["episode"])
    return summarise(records)


def _states(td, envs, played, n: int, on_state: Sink | None, need=None) -> None:
    """The snapshot taken at the start of each new episode of ``envs``."""
    if on_state is None or "states" not in td:
        return
    flat = td.reshape(-1)
    for i in envs:
        if need is None or played[i] < need[i]:
            for msg in rows_to_messages(flat[i]["states"].numpy(), i + n * int(played[i])):
                on_state(msg)


def _action(row, episode: int, step: int, names: Sequence[str] | None) -> Record:
    a = int(row["action"])
    nxt = row["next"]
    return {"episode": episode, "step": step, "action": a,
            "name": names[a] if names is not None else str(a),
            "valid": bool(nxt["valid"]), "outcome": OUTCOMES[int(nxt["outcome"])],
            "pose_before": row["pose"].tolist(), "pose_after": nxt["pose"].tolist(),
            "sim_time_s": float(nxt["sim_time_s"]), "reward": float(nxt["reward"])}


def _episode(last, pair: GoalPair, episode: int, n_actions: int, n_invalid: int) -> Record:
    success, dropped = bool(last["success"]), bool(last["dropped"])
    final = last["pose"].double().numpy()
    ex, ez, eth = pose_error(final, pair.xg)
    return {"episode": episode, "group": pair.group, "success": success,
            "dropped": dropped, "timeout": not (success or dropped),
            "sim_time_s": float(last["sim_time_s"]), "n_actions": n_actions,
            "n_invalid": n_invalid, "x0": pair.x0.tolist(), "xg": pair.xg.tolist(),
            "final_pose": final.tolist(), "final_err_m": float(np.hypot(ex, ez)),
            "final_err_rad": float(eth), "needs_flip": bool(pair.needs_flip),
            "lone_down": bool(pair.lone_down)}


def _flipped(records: list[Record], prefix: str = "") -> dict[str, int]:
    """How many of ``records`` made a flip, and how many of those succeeded; nothing when
    they do not count their flips."""
    counted = [r for r in records if "n_flips" in r]
    if not counted:
        return {}
    made = [r for r in counted if r["n_flips"] > 0]
    return {f"{prefix}flipped": len(made),
            f"{prefix}flipped_success": sum(r["success"] for r in made)}


def summarise(records: list[Record]) -> dict[str, float]:
    n = len(records)
    wins = [r for r in records if r["success"]]
    out: dict[str, float] = {"episodes": n}
    flips = any(r.get("needs_flip") for r in records)
    subsets = {"needs_flip": lambda r: r.get("needs_flip"),  # the subsets the goal set flags
               "no_flip": lambda r: flips and not r.get("needs_flip"),  # the others, if any
               "lone_down": lambda r: r.get("lone_down")}
    for flag, member in subsets.items():
        some = [r for r in records if member(r)]
        out[flag] = len(some)
        out[f"{flag}_success_rate"] = (sum(r["success"] for r in some) / len(some)
                                       if some else float("nan"))
        out[f"{flag}_drop_rate"] = (sum(r["dropped"] for r in some) / len(some)
                                    if some else float("nan"))
        out.update(_flipped(some, f"{flag}_"))
    out.update(_flipped(records))
    return {**out,
            "success_rate": len(wins) / n,
            "drop_rate": sum(r["dropped"] for r in records) / n,
            "timeout_rate": sum(r["timeout"] for r in records) / n,
            "avg_time_s": float(np.mean([r["sim_time_s"] for r in wins])) if wins else float("nan")}
