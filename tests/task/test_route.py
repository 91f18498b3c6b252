"""The route shaping: the search graph's route time as a potential, read from the state, and the
reward it pays in the mid-level environment."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from inhand_exp.config import SearchConfig
from inhand_exp.control.grasp import Contacts
from inhand_exp.envs.primitive_env import PrimitiveEnv
from inhand_exp.task.actions import action_table
from inhand_exp.task.goals import GoalPair
from inhand_exp.task.graph import cached_graph
from inhand_exp.task.route import ADVICE_SCALE_S, RouteAdvice, RouteTime

# the search tests' TINY workspace: the pole held high enough to flip
TINY = ("task.workspace_x_m=[-0.02,0.02]", "task.workspace_z_m=[0.40,0.44]",
        "task.workspace_theta_rad=[-0.2,0.2]")


@pytest.fixture(scope="module")
def graph_dir(tmp_path_factory):
    """One graph cache for this module: the first test builds the TINY graph, the next reads it."""
    return tmp_path_factory.mktemp("route-graph")


def _cfg(compose_cfg, cache, *more):
    cfg = compose_cfg(*TINY, f"task.route_cache_dir={cache}", *more)
    return cfg, SearchConfig(cache_dir=str(cache))


def test_the_route_time_is_the_graphs_distance_from_the_states_cell(compose_cfg, graph_dir):
    """At a node's own grasp and pose, the route time is the graph's distance from that node
    (capped); a goal the graph has no route to gives the cap."""
    from inhand_exp.control.hand import HandModel

    cfg, params = _cfg(compose_cfg, graph_dir)
    g = cached_graph(cfg, params)
    model = HandModel.from_config(cfg.hand, cfg.object, cfg.sim.gravity_mps2)
    route = RouteTime(g, model, cap_s=20.0)
    lat = g.lattice
    goal = np.array([lat.xs[0], lat.zs[0], lat.ts[0]])
    d = g.distances_to(goal)
    rng = np.random.default_rng(0)
    cells = [tuple(ix) for ix, n in np.ndenumerate(g.ids) if n >= 0]
    seen = {"finite": 0, "capped": 0}
    for k in rng.choice(len(cells), 40, replace=False):
        cell = cells[k]
        pose = np.array([lat.xs[cell[4]], lat.zs[cell[5]], lat.ts[cell[6]]])
        contacts = Contacts(g.postures[cell[0]], tuple(float(lat.cs[j]) for j in cell[1:4]))
        got = route(model.grasp_q(contacts, pose), pose, goal)
        want = min(20.0, float(d[g.ids[cell]]))
        assert got == pytest.approx(want), cell
        seen["finite" if want < 20.0 else "capped"] += 1
    assert seen["finite"] > 0, seen
    with pytest.raises(ValueError, match="cap_s"):
        RouteTime(g, model, cap_s=0.0)


def test_the_route_shaping_pays_the_route_time_an_action_saves(compose_cfg, graph_dir):
    """``task.reward_route`` pays, per action, the route time before minus after, read from the
    simulated state, on top of the paper's reward; without it the reward has no such term."""
    cfg, params = _cfg(compose_cfg, graph_dir, "task.reward_route=1.0")
    g = cached_graph(cfg, params)
    lat = g.lattice
    cell = next(tuple(ix) for ix, n in np.ndenumerate(g.ids) if n >= 0)
    x0 = np.array([lat.xs[cell[4]], lat.zs[cell[5]], lat.ts[cell[6]]])
    contacts = Contacts(g.postures[cell[0]], tuple(float(lat.cs[j]) for j in cell[1:4]))
    pair = GoalPair("medium", x0, x0 + np.array([0.0, 0.03, 0.0]), contacts)
    env = PrimitiveEnv(cfg, goals=[pair], seed=0)
    try:
        td = env.reset()
        task = env.task
        assert task.route is not None
        paid = 0
        for _ in range(8):
            allowed = [a for a in np.flatnonzero(td["action_mask"].numpy())
                       if env.actions[a].kind == "repose"]
            a = int(allowed[0])
            before = task.route_to_go()
            td = env.step(td.set("action", torch.tensor(a)))["next"]
            after = task.route_to_go()
            if bool(td["done"]):
                break
            invalid = 0.0 if bool(td["valid"]) else cfg.task.reward_invalid
            assert float(td["reward"]) == pytest.approx(before - after + invalid, abs=1e-6)
            paid += before != after
        assert paid > 0
    finally:
        env.close()


def test_the_advice_is_zero_along_a_shortest_route_and_one_where_an_action_has_no_edge(
        compose_cfg, graph_dir):
    """At a node, the route time is its distance over the cap, and each action's advice is
    its edges' time plus the time from their ends, less that distance: the best action reads
    0 (Dijkstra's identity: a node's distance is its best edge plus the distance beyond), none
    reads less, and an action without an edge reads 1."""
    from inhand_exp.control.hand import HandModel

    cfg, params = _cfg(compose_cfg, graph_dir)
    g = cached_graph(cfg, params)
    model = HandModel.from_config(cfg.hand, cfg.object, cfg.sim.gravity_mps2)
    actions = action_table(cfg.primitives)
    advice = RouteAdvice(g, model, actions, cap_s=20.0)
    lat = g.lattice
    goal = np.array([lat.xs[-1], lat.zs[-1], lat.ts[-1]])
    d = g.distances_to(goal)
    cells = [tuple(ix) for ix, n in np.ndenumerate(g.ids) if n >= 0 and 0 < d[n] < 20.0]
    assert len(cells) > 10
    rng = np.random.default_rng(1)
    for k in rng.choice(len(cells), 10, replace=False):
        cell = cells[k]
        pose = np.array([lat.xs[cell[4]], lat.zs[cell[5]], lat.ts[cell[6]]])
        contacts = Contacts(g.postures[cell[0]], tuple(float(lat.cs[j]) for j in cell[1:4]))
        got = advice(model.grasp_q(contacts, pose), pose, goal)
        assert got.shape == (1 + len(actions),)
        assert got[0] == pytest.approx(d[g.ids[cell]] / 20.0)
        assert got[1:].min() == pytest.approx(0.0, abs=1e-9), cell
        for a in actions:
            ends = [int(g.ids[t]) for t in g.successors(cell, a) if g.ids[t] >= 0]
            best = min((d[n] + g.weight(int(g.ids[cell]), n) for n in ends), default=np.inf)
            want = 1.0 if not np.isfinite(best) else min(
                1.0, (best - d[g.ids[cell]]) / ADVICE_SCALE_S)
            assert got[1 + a.index] == pytest.approx(want), (cell, a.name)
    off = advice(model.grasp_q(contacts, pose), pose, np.array([9.0, 9.0, 0.0]))
    np.testing.assert_array_equal(off, np.ones(1 + len(actions)))  # no route: all ones


def test_route_advice_extends_the_observation_and_a_policy_for_the_other_size_is_refused(
        compose_cfg, graph_dir, tmp_path):
    from inhand_exp.errors import CheckpointError
    from inhand_exp.learn import ppo

    plain = compose_cfg(*TINY, f"task.route_cache_dir={graph_dir}")
    advised = compose_cfg(*TINY, f"task.route_cache_dir={graph_dir}", "task.route_advice=true")
    sizes = []
    for cfg in (plain, advised):
        env = PrimitiveEnv(cfg, seed=0)
        try:
            sizes.append(env.reset()["observation"].shape[-1])
            assert env.observation_spec["observation"].shape[-1] == sizes[-1]
        finally:
            env.close()
        assert ppo.from_config(cfg).obs_dim == sizes[-1]
    assert sizes == [18, 18 + 1 + 14]
    path = tmp_path / "plain.pt"
    ppo.from_config(plain).save(path)
    with pytest.raises(CheckpointError, match="18 observations.*task.route_advice=true adds 15"):
        ppo.from_config(advised).load(path)
