"""Batched primitive environments: layout, seeding, and Serial = Parallel evaluation."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest
import torch

from inhand_exp.control.hand import HandModel
from inhand_exp.envs.batched import batched_env, layout, split_goals
from inhand_exp.learn.evaluate import evaluate
from inhand_exp.learn.ppo import make_networks
from inhand_exp.task.goals import goal_set

SMALL = ("train.num_envs=2", "task.max_actions=3", "noise=paper")


def small_goals(cfg, n: int):
    model = HandModel.from_config(cfg.hand, cfg.object, cfg.sim.gravity_mps2)
    return goal_set(model, "easy", n, cfg.goals.seed)


def test_layout_caps_workers_and_splits_evenly(compose_cfg):
    assert layout(compose_cfg("train.num_envs=16", "train.workers=2")) == (2, 8)
    assert layout(compose_cfg("train.num_envs=16", "train.workers=1")) == (1, 16)
    with pytest.warns(UserWarning, match="using 1 worker processes"):
        assert layout(compose_cfg("train.num_envs=3", "train.workers=2")) == (1, 3)
    too_many = (os.cpu_count() or 1) + 1
    with pytest.warns(UserWarning, match="cores"):
        workers, per = layout(compose_cfg(f"train.num_envs={too_many * 4}",
                                          f"train.workers={too_many}"))
    assert workers <= (os.cpu_count() or 1) and workers * per == too_many * 4


def test_goals_are_dealt_round_robin_and_never_too_few(compose_cfg):
    goals = small_goals(compose_cfg(), 5)
    dealt = split_goals(goals, 2)
    assert [len(d) for d in dealt] == [3, 2]
    assert dealt[0][1] is goals[2] and dealt[1][0] is goals[1]
    with pytest.raises(ValueError, match="cannot feed 8 environments"):
        split_goals(goals, 8)


def test_sub_environments_get_different_derived_seeds(compose_cfg):
    env = batched_env(compose_cfg(*SMALL, "train.backend=serial", "train.workers=1"), seed=3)
    td = env.reset()
    first, second = td["observation"].reshape(2, -1)
    assert not torch.equal(first, second)  # different training pairs
    again = batched_env(compose_cfg(*SMALL, "train.backend=serial", "train.workers=1"), seed=3)
    assert torch.equal(again.reset()["observation"], td["observation"])
    env.close()
    again.close()


def test_serial_and_parallel_evaluations_are_identical(compose_cfg):
    cfg = compose_cfg(*SMALL, "train.workers=2")
    goals = small_goals(cfg, 5)
    torch.manual_seed(0)
    actor, _ = make_networks(18, 14, (32,))
    runs = {}
    for backend, once in (("serial", True), ("parallel", True), ("serial", False)):
        cfg.train.backend = backend
        env = batched_env(cfg, seed=11, goals=goals, states_hz=10.0, once=once)
        episodes, actions, states = [], [], []
        torch.manual_seed(5)  # the sampled actions are drawn in this process
        summary = evaluate(env, actor, goals, episodes.append, actions.append, states.append,
                           sample=True)
        env.close()
        runs[backend, once] = summary, episodes, actions, states
    serial, parallel = runs["serial", True], runs["parallel", True]
    np.testing.assert_equal(serial[0], parallel[0])  # NaN mean time when nothing succeeds
    assert serial[1:] == parallel[1:]
    assert runs["serial", False][1:] == serial[1:]  # idling after the last goal changes nothing
    summary, episodes, actions, states = serial
    assert sorted(e["episode"] for e in episodes) == list(range(5))
    for e in episodes:  # episode k plays goal k
        np.testing.assert_allclose(e["xg"], goals[e["episode"]].xg)
    assert len(actions) == sum(e["n_actions"] for e in episodes)
    assert {s["episode"] for s in states} == set(range(5))
    for k in range(5):
        times = [s["sim_time_s"] for s in states if s["episode"] == k]
        assert times[0] == 0.0 and all(np.diff(times) > 0)


def test_parallel_main_process_sleeps_while_the_workers_step(compose_cfg):
    """The main process waits without spinning: it uses little CPU while the workers step
    (a spinning wait would use all of its wall time and take a core from the workers)."""
    env = batched_env(compose_cfg(*SMALL, "train.workers=2", "train.backend=parallel"), seed=0)
    try:
        td = env.reset()
        cpu, wall = time.process_time(), time.perf_counter()
        for _ in range(3):
            td["action"] = torch.zeros(td.shape, dtype=torch.long)  # repose +x
            td, root = env.step_and_maybe_reset(td)
            td = root
        cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    finally:
        env.close()
    assert cpu < 0.3 * wall, (cpu, wall)  # spinning: about 0.7 here


def test_an_interrupt_while_the_batch_is_built_waits_until_it_is_built(compose_cfg,
                                                                         monkeypatch):
    """A SIGTERM that comes while the environments are being made (here: as each row starts)
    is raised once the batch stands, and the batch is closed: it never lands half-way through
    OmegaConf or PyBullet building an environment."""
    import signal

    from inhand_exp.envs import batched

    made, closed = [], []
    make_row = batched._make_row

    def row_after_a_sigterm(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)
        made.append(make_row(*args, **kwargs))
        return made[-1]

    def interrupted(signum, frame):
        raise KeyboardInterrupt(signum)

    close = batched.SerialEnv.close
    monkeypatch.setattr(batched, "_make_row", row_after_a_sigterm)
    monkeypatch.setattr(batched.SerialEnv, "close",
                        lambda self, **kw: (closed.append(self), close(self, **kw))[1])
    before = signal.signal(signal.SIGTERM, interrupted)
    try:
        with pytest.raises(KeyboardInterrupt):
            batched_env(compose_cfg(*SMALL, "train.backend=serial", "train.workers=2"), 0)
    finally:
        signal.signal(signal.SIGTERM, before)
    assert len(made) >= 2  # every row was made: the signal waited
    assert any(type(env) is batched.SerialEnv for env in closed)  # the batch, closed
