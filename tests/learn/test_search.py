"""The graph-search baseline: Dijkstra's distances, the graph's edges executed in physics, the
on-disk cache and clean refusals."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy import sparse

from inhand_exp.config import ConfigError, HandConfig, ObjectConfig
from inhand_exp.control.grasp import Contacts, Face, Posture
from inhand_exp.control.hand import HandModel
from inhand_exp.control.sample import Workspace
from inhand_exp.envs.batched import batched_env
from inhand_exp.envs.primitive_env import PrimitiveEnv
from inhand_exp.learn.search import Search, SearchPolicy
from inhand_exp.task.goals import GoalPair
from inhand_exp.task.graph import Lattice, PoseGraph
from inhand_exp.task.rules import to_go

# held high enough for a flip's finger to pass under the pole's lower end (``way_table``)
TINY = ("learner=search", "task.workspace_x_m=[-0.02,0.02]", "task.workspace_z_m=[0.40,0.44]",
        "task.workspace_theta_rad=[-0.2,0.2]")


@pytest.fixture(scope="module")
def tiny_graph_dir(tmp_path_factory):
    """One graph cache for the tests that read the TINY graph: the first of them builds it (8 s),
    the others load it. The tests of building and caching use their own directories."""
    return tmp_path_factory.mktemp("tiny-graph")


def observation(search: Search, contacts: Contacts, pose: np.ndarray,
                goal: np.ndarray) -> np.ndarray:
    """The primitive environment's observation of the hand at rest in ``contacts`` at ``pose``,
    with ``goal``: joints, pose and goal set, velocities zero."""
    obs = np.zeros(18)
    obs[:6], obs[12:15], obs[15:18] = search.model.grasp_q(contacts, pose), pose, goal
    return obs


def test_dijkstra_finds_the_known_shortest_paths_of_a_small_graph():
    """A hand-built graph over 6 nodes: 0-1 (1 s), 1-2 (1 s), 0-2 (5 s), 2-3 (2 s) both ways;
    one way only 5->0 (1 s) and 3->4 (1 s)."""
    lat = Lattice(np.array([0.0]), np.array([0.3]), 0.1 * np.arange(6), np.array([0.0]))
    ids = np.arange(6, dtype=np.int32).reshape(1, 1, 1, 1, 1, 1, 6)
    r, c, w = [0, 1, 0, 2], [1, 2, 2, 3], [1.0, 1.0, 5.0, 2.0]
    r, c, w = r + c + [5, 3], c + r + [0, 4], w + w + [1.0, 1.0]
    m = sparse.coo_matrix((w, (r, c)), shape=(6, 6)).tocsr()
    g = PoseGraph(lat, [None], ids, m)
    goal = np.array([0.0, 0.3, 0.3])  # the goal cell is node 3
    np.testing.assert_allclose(g.distances_to(goal), [4.0, 3.0, 2.0, 0.0, np.inf, 5.0])
    assert g.edges == 10 and g.nodes == 6
    assert g.weight(5, 0) == 1.0 and g.weight(0, 5) == np.inf and g.weight(0, 2) == 5.0
    # node 4 has no edge out (the goal at 3 is out of its reach); it is reached by 3->4
    np.testing.assert_allclose(g.distances_to(np.array([0.0, 0.3, 0.4])),
                               [5.0, 4.0, 3.0, 1.0, 0.0, 6.0])
    assert np.isinf(g.distances_to(np.array([0.0, 0.3, 2.0]))).all()  # outside the lattice
    # a cut edge is cut one way only
    np.testing.assert_allclose(g.distances_to(goal, {(1, 2)}), [7.0, 8.0, 2.0, 0.0, np.inf, 8.0])
    np.testing.assert_allclose(g.distances_to(goal, {(2, 1)}), [4.0, 3.0, 2.0, 0.0, np.inf, 5.0])
    np.testing.assert_allclose(g.distances_to(goal, {(0, 2), (2, 3)}), [np.inf] * 3 + [0] +
                               [np.inf] * 2)
    np.testing.assert_allclose(g.distances_to(goal), [4.0, 3.0, 2.0, 0.0, np.inf, 5.0])
    # a spent goal node is no end: with node 3 spent, the goal cell holds no other
    assert np.isinf(g.distances_to(goal, spent={3})).all()


def test_a_goal_cell_no_lattice_grasp_holds_ends_the_plan_next_to_it():
    """Where no node lies in the goal's pose cell (the goal is held, by a grasp between the
    lattice's points), the plan ends in the pose cells one step from it; a goal cell with
    nodes keeps its own."""
    lat = Lattice(np.array([0.0]), np.array([0.3]), 0.1 * np.arange(5), np.array([0.0]))
    ids = np.array([0, 1, 2, -1, 3], dtype=np.int32).reshape(1, 1, 1, 1, 1, 1, 5)
    r, c, w = [0, 1, 2], [1, 2, 3], [1.0, 1.0, 4.0]  # a chain, both ways; 2-3 jumps the gap
    m = sparse.coo_matrix((w + w, (r + c, c + r)), shape=(4, 4)).tocsr()
    g = PoseGraph(lat, [None], ids, m)
    np.testing.assert_allclose(g.distances_to(np.array([0.0, 0.3, 0.3])), [2.0, 1.0, 0.0, 0.0])
    np.testing.assert_allclose(g.distances_to(np.array([0.0, 0.3, 0.3]), spent={2}),
                               [6.0, 5.0, 4.0, 0.0])
    np.testing.assert_allclose(g.distances_to(np.array([0.0, 0.3, 0.2])), [2.0, 1.0, 0.0, 4.0])


def test_a_refused_best_edge_is_cut_and_the_walk_plans_again(compose_cfg, tiny_graph_dir):
    """When the filter refuses the action of the best edge, the walk takes the best edge of
    the graph without it, and never plans through it again in that episode."""
    search = Search(compose_cfg(*TINY, f"learner.cache_dir={tiny_graph_dir}"))
    g, policy = search.ensure_graph(), search.policy
    lat = g.lattice
    goal = np.array([lat.xs[0], lat.zs[0], lat.ts[0]])
    d = g.distances_to(goal)

    def value(cell, a, dist):  # the best edge's time to the goal by action ``a``
        here = int(g.ids[cell])
        return min((g.weight(here, int(g.ids[t])) + dist[g.ids[t]]
                    for t in policy.successors(cell, a) if g.ids[t] >= 0), default=np.inf)

    for cell in (tuple(ix) for ix, n in np.ndenumerate(g.ids) if n >= 0 and 0 < d[n] < np.inf):
        ranked = sorted(policy.actions, key=lambda a, c=cell: value(c, a, d))
        if value(cell, ranked[1], d) < np.inf:  # a second way on
            break
    here, best = int(g.ids[cell]), ranked[0]
    pose = np.array([lat.xs[cell[4]], lat.zs[cell[5]], lat.ts[cell[6]]])
    contacts = Contacts(g.postures[cell[0]], tuple(float(lat.cs[k]) for k in cell[1:4]))
    obs = observation(search, contacts, pose, goal)
    mask = np.ones(len(policy.actions), dtype=bool)
    assert policy.act(0, obs, mask) == best.index
    # what failed from off the graph is not left out on it: the walk and its distances agree
    policy.walks[0].edge = None
    policy.walks[0].blocked.update((t, best.index) for t in policy.successors(cell, best))
    assert policy.act(0, obs, mask) == best.index
    policy.walks.clear()
    mask[best.index] = False
    chosen = policy.act(0, obs, mask)
    walk = policy.walks[0]
    cut = {(here, int(g.ids[t])) for t in policy.successors(cell, best) if g.ids[t] >= 0}
    assert cut <= walk.cut and chosen != best.index
    again = g.distances_to(goal, walk.cut)
    np.testing.assert_array_equal(walk.field, again)
    assert value(cell, policy.actions[chosen], again) == min(
        value(cell, a, again) for a in policy.actions if a.index != best.index)


def test_a_goal_node_the_walk_comes_back_to_no_closer_is_spent(compose_cfg, tiny_graph_dir):
    """At a node of the goal cell whose last reposes the filter refuses, the walk that comes
    back there no closer to the goal plans on to the goal cell's other nodes."""
    search = Search(compose_cfg(*TINY, f"learner.cache_dir={tiny_graph_dir}"))
    g, policy = search.ensure_graph(), search.policy
    lat = g.lattice
    for cell in (tuple(ix) for ix, n in np.ndenumerate(g.ids) if n >= 0):
        pose = np.array([lat.xs[cell[4]], lat.zs[cell[5]], lat.ts[cell[6]]])
        goal = pose + [0.008, 0.0, 0.08]  # in the same pose cell, not reached
        here = int(g.ids[cell])
        if np.isfinite(g.distances_to(goal, spent={here})[here]):
            break
    contacts = Contacts(g.postures[cell[0]], tuple(float(lat.cs[k]) for k in cell[1:4]))
    obs = observation(search, contacts, pose, goal)
    mask = np.array([a.kind != "repose" for a in policy.actions])  # every repose refused
    policy.act(0, obs, mask)  # at the goal cell: the closest allowed action
    walk = policy.walks[0]
    assert not walk.spent and walk.field is None
    chosen = policy.actions[policy.act(0, obs, mask)]  # back, no closer: spent
    assert walk.spent == {here}
    np.testing.assert_array_equal(walk.field, g.distances_to(goal, spent={here}))
    ends = [int(g.ids[t]) for t in policy.successors(cell, chosen)]
    assert any(n >= 0 and n != here and walk.field[n] < walk.field[here] for n in ends)


def test_off_the_plan_the_walk_tries_new_grasps_instead_of_going_back(compose_cfg,
                                                                      tiny_graph_dir):
    """Where the graph has no path (here a goal off its lattice), the walk searches locally
    (LRTA*): it first takes the allowed repose that brings the object closest to the goal;
    where every repose is refused it slides, and it does not slide straight back to the grasp
    it has just left while a grasp not tried yet is allowed."""
    search = Search(compose_cfg(*TINY, f"learner.cache_dir={tiny_graph_dir}"))
    g, policy = search.ensure_graph(), search.policy
    lat, dc = g.lattice, search.prim.slide_dc_m
    cell = next(tuple(ix) for ix, n in np.ndenumerate(g.ids) if n >= 0)
    pose = np.array([lat.xs[cell[4]], lat.zs[cell[5]], lat.ts[cell[6]]])
    goal = pose + [0.0, 0.0, 1.0]  # theta off the lattice: no plan
    assert np.isinf(g.distances_to(goal)).all()
    posture = g.postures[cell[0]]
    names = {a.name: a.index for a in policy.actions}

    def observe(coords):
        return observation(search, Contacts(posture, tuple(float(c) for c in coords)), pose,
                           goal)

    at = [float(lat.cs[k]) for k in cell[1:4]]
    mask = np.ones(len(policy.actions), dtype=bool)
    assert policy.act(0, observe(at), mask) == names["repose +theta"]
    policy.walks.clear()
    mask = np.array([a.kind == "slide" for a in policy.actions])
    first = policy.actions[policy.act(0, observe(at), mask)]
    assert first.kind == "slide"
    there = list(at)
    there[first.finger] += first.dc
    back = next(a for a in policy.actions if a.kind == "slide" and a.finger == first.finger
                and a.dc == -first.dc)
    assert abs(first.dc) == dc
    chosen = policy.actions[policy.act(0, observe(there), mask)]
    assert chosen.kind == "slide" and chosen.index != back.index
    # the grasp left behind now costs more than the slide that leaves it
    walk = policy.walks[0]
    start = policy.key(walk, policy.contacts(observe(at)[:6], pose), pose)
    assert walk.estimate[start] >= to_go(pose, goal, search.rules) + 1.0


def test_the_local_search_knows_a_place_again_across_a_step_edge(compose_cfg, tiny_graph_dir):
    """LRTA*'s states are the places the walk has been. A pose half a repose step off the
    1 cm grid (where the graph's walk leaves the object), met again micrometres to the other
    side of that grid's edge, is the same state and keeps its raised estimate; a repose step
    away is another state. (Keyed by the grid, the walk went back and forth between two
    poses for the rest of an episode, each visit a new state.)"""
    search = Search(compose_cfg(*TINY, f"learner.cache_dir={tiny_graph_dir}"))
    g, policy = search.ensure_graph(), search.policy
    lat, dx = g.lattice, search.prim.repose_dx_m
    cell = next(tuple(ix) for ix, n in np.ndenumerate(g.ids) if n >= 0)
    contacts = Contacts(g.postures[cell[0]], tuple(float(lat.cs[k]) for k in cell[1:4]))
    edge = np.array([(round(lat.xs[cell[4]] / dx) + 0.5) * dx, lat.zs[cell[5]], lat.ts[cell[6]]])
    goal = edge + [0.0, 0.0, 1.0]  # theta off the lattice: no plan, the walk searches locally
    jitter = np.array([2e-6, 0.0, 0.0])
    names = {a.name: a.index for a in policy.actions}
    mask = np.zeros(len(policy.actions), dtype=bool)
    mask[[names["repose +x"], names["repose -x"]]] = True
    policy.act(0, observation(search, contacts, edge - jitter, goal), mask)
    walk = policy.walks[0]
    first = policy.key(walk, contacts, edge - jitter)
    raised = walk.estimate[first]
    assert raised > to_go(edge, goal, search.rules)
    assert policy.key(walk, contacts, edge + jitter) == first
    step = policy.key(walk, contacts, edge + [dx, 0.0, 0.0])
    assert step != first and len(walk.states) == 2
    policy.act(0, observation(search, contacts, edge + jitter, goal), mask)
    assert len(walk.states) == 2 and walk.estimate[first] >= raised


def test_next_to_a_goal_cell_without_a_node_the_walk_searches_locally_from_then_on(
        compose_cfg, tiny_graph_dir):
    """With the goal's pose cell emptied of nodes, the plan ends next to it; at such an end
    the walk searches locally (LRTA*), and goes on doing so from a node the plan would lead
    somewhere else, instead of being sent back to the end it has left."""
    search = Search(compose_cfg(*TINY, f"learner.cache_dir={tiny_graph_dir}"))
    g = search.ensure_graph()
    lat = g.lattice
    ids = g.ids.copy()
    ids[..., 0, 0, 0] = -1  # a corner pose cell: no grasp on the lattice holds it
    bare = PoseGraph(lat, g.postures, ids, g.matrix)
    policy = SearchPolicy(bare, search.model, search.prim, search.rules, search.policy.actions)
    goal = np.array([lat.xs[0], lat.zs[0], lat.ts[0]])
    d = bare.distances_to(goal)
    ends = set(np.flatnonzero(d == 0.0))
    beside = ids[..., 1, 0, 0]  # a pose cell next to it: all its nodes are ends
    assert beside.max() >= 0 and set(beside[beside >= 0].tolist()) <= ends
    cell = next(c for c, n in np.ndenumerate(ids) if n in ends)
    far = next(c for c, n in np.ndenumerate(ids) if n >= 0 and 0.0 < d[n] < np.inf)

    def observe(c):
        pose = np.array([lat.xs[c[4]], lat.zs[c[5]], lat.ts[c[6]]])
        contacts = Contacts(bare.postures[c[0]], tuple(float(lat.cs[k]) for k in c[1:4]))
        return observation(search, contacts, pose, goal)

    mask = np.ones(len(policy.actions), dtype=bool)
    policy.act(1, observe(far), mask)  # a walk from afar follows the plan
    fresh = policy.walks[1]
    assert fresh.bare and not fresh.local and fresh.edge is not None
    assert d[ids[fresh.edge[1]]] < d[ids[far]]
    policy.act(0, observe(cell), mask)
    walk = policy.walks[0]
    assert walk.local and walk.edge is None
    policy.act(0, observe(far), mask)
    assert walk.local and walk.edge is None  # not sent back along the plan


def test_the_end_contact_cells_take_the_ends_of_the_face():
    lat = Lattice(np.zeros(1), np.zeros(1), np.zeros(1), 0.05 * np.arange(-4, 5))
    assert lat.contact_cell(0.12) == 6 and lat.contact_cell(-0.2249) == 0
    assert lat.contact_cell(0.226) is None  # more than half a cell past the last
    assert lat.contact_cell(0.226, reach=0.235) == 8 and lat.contact_cell(-0.235, 0.235) == 0
    assert lat.contact_cell(0.24, reach=0.235) is None


def test_resolutions_must_be_positive():
    model = HandModel.from_config(HandConfig(), ObjectConfig(), 9.81)
    for bad in ((0.0, 0.2, 0.05), (0.02, -0.2, 0.05), (0.02, 0.2, 0.0)):
        with pytest.raises(ValueError, match="must be > 0"):
            Lattice.build(model, Workspace(), *bad)


def test_config_refuses_bad_resolutions_and_oversized_lattices(compose_cfg, tmp_path):
    from inhand_exp.config import validate

    with pytest.raises(ConfigError, match="learner.resolution_m must be > 0"):
        validate(compose_cfg("learner=search", "learner.resolution_m=0"))
    cfg = compose_cfg("learner=search", "learner.max_cells=1000",
                      f"learner.cache_dir={tmp_path}")
    with pytest.raises(ConfigError, match="more than learner.max_cells=1,000"):
        Search(cfg).ensure_graph()


def path_edges(search: Search, start: int, goal: np.ndarray, most: int = 4):
    """The first edges (start cell, end cell, action) of the shortest path from ``start``."""
    g, policy = search.graph, search.policy
    d = g.distances_to(goal)
    cells = {int(n): tuple(ix) for ix, n in np.ndenumerate(g.ids) if n >= 0}
    out, n = [], start
    while d[n] > 0 and len(out) < most:
        row = g.matrix.getrow(n)
        m = int(row.indices[np.argmin(row.data + d[row.indices])])
        a, b = cells[n], cells[m]
        action = next(x for x in search.actions
                      if x.kind != "flip" and b in policy.successors(a, x))
        out.append((a, b, action))
        n = m
    return out


def test_every_edge_of_a_plan_executes_with_the_controllers(compose_cfg, tmp_path):
    cfg = compose_cfg(*TINY, f"learner.cache_dir={tmp_path}", "learner.resolution_m=0.02",
                      "learner.resolution_rad=0.2", "primitives.flip=false")
    search = Search(cfg)
    g = search.ensure_graph()
    assert g.nodes > 50 and g.edges > g.nodes
    lat = g.lattice
    goal = np.array([lat.xs[-1], lat.zs[-1], lat.ts[-1]])
    d = g.distances_to(goal)
    far = [n for n in np.flatnonzero(np.isfinite(d)) if d[n] >= 3.0]
    assert far, "no node three steps from the goal corner"
    edges = path_edges(search, int(far[0]), goal)
    assert len(edges) >= 3
    policy = search.policy
    for a, b, action in edges:
        p, k, cell = a[0], a[1:4], a[4:]
        pose = np.array([lat.xs[cell[0]], lat.zs[cell[1]], lat.ts[cell[2]]])
        contacts = Contacts(g.postures[p], tuple(float(lat.cs[j]) for j in k))
        env = PrimitiveEnv(cfg, goals=[GoalPair("easy", pose, goal, contacts)], seed=0)
        td = env.reset()
        arrived = False
        for _ in range(policy.budget[action.index]):
            assert td["action_mask"][action.index], (a, action.name)
            td = env.step(td.set("action", torch.tensor(action.index)))["next"]
            assert not td["dropped"].item()
            obs = td["observation"].double().numpy()
            if policy.cell(policy.contacts(obs[:6], obs[12:15]), obs[12:15]) == b:
                arrived = True
                break
        env.close()
        assert arrived, (a, b, action.name)


def test_the_graph_is_cached_by_what_shapes_it(compose_cfg, tmp_path):
    a = Search(compose_cfg(*TINY, f"learner.cache_dir={tmp_path}"))
    g = a.ensure_graph()
    assert a.cache.is_file() and "load_s" not in a.stats
    b = Search(compose_cfg(*TINY, f"learner.cache_dir={tmp_path}"))
    h = b.ensure_graph()
    assert "load_s" in b.stats and (h.matrix != g.matrix).nnz == 0
    assert np.array_equal(h.ids, g.ids) and h.postures == g.postures
    other = Search(compose_cfg(*TINY, f"learner.cache_dir={tmp_path}", "object.width_m=0.03"))
    assert other.cache != a.cache
    assert Search(compose_cfg(*TINY, f"learner.cache_dir={tmp_path}",
                              "learner.resolution_rad=0.1")).cache != a.cache


def test_search_plays_easy_pairs_to_the_goal(compose_cfg, tmp_path):
    from inhand_exp.control.hand import HandModel as HM
    from inhand_exp.learn.evaluate import evaluate
    from inhand_exp.task.goals import goal_set

    cfg = compose_cfg("learner=search", f"learner.cache_dir={tmp_path}", "goals=easy",
                      "train.num_envs=2", "train.backend=serial")
    search = Search(cfg)
    model = HM.from_config(cfg.hand, cfg.object, cfg.sim.gravity_mps2)
    goals = goal_set(model, "easy", 4, seed=1234)
    env = batched_env(cfg, 0, goals=goals, num_envs=2, once=True, env_class=search.env_class)
    try:
        summary = evaluate(env, search.policy, goals)
    finally:
        env.close()
    assert summary["success_rate"] >= 0.75, summary


def test_flip_edges_are_the_flips_the_primitive_makes(compose_cfg, tiny_graph_dir):
    """A flip edge moves finger 0 or 2 and leaves its pose and the staying pair's contacts as
    they are; the flip primitive itself starts from its cell (the pair holds the object alone
    and the finger has a clear way round the pole's end, ``flip.Flip.start``). Where the graph
    has no flip edge although the pair opposes and the flipped posture holds the pole there,
    the primitive refuses the flip too: about half of those because the pair cannot hold the
    pole alone, the others for want of a way round the end (``graph.way_table``)."""
    from inhand_exp.control.execute import Observation
    from inhand_exp.control.flip import Flip, pair_holds

    cfg = compose_cfg(*TINY, f"learner.cache_dir={tiny_graph_dir}")
    search = Search(cfg)
    g = search.ensure_graph()
    model, lat = search.model, g.lattice
    cells = {int(n): tuple(ix) for ix, n in np.ndenumerate(g.ids) if n >= 0}
    coo = g.matrix.tocoo()

    def state(cell: tuple) -> tuple[Contacts, Observation]:
        pose = np.array([lat.xs[cell[4]], lat.zs[cell[5]], lat.ts[cell[6]]])
        contacts = Contacts(g.postures[cell[0]], tuple(float(lat.cs[k]) for k in cell[1:4]))
        return contacts, Observation(model.grasp_q(contacts, pose), np.zeros(6), pose,
                                     np.zeros(3), 0.0)

    def holds_alone(cell: tuple, f: int) -> bool:
        contacts, obs = state(cell)
        return not isinstance(pair_holds(model, contacts, f, obs, cfg.primitives), str)

    def flip_refuses(cell: tuple, f: int) -> str | None:
        contacts, obs = state(cell)
        return Flip(model, contacts, f, cfg.primitives.flip_duration_s,
                    cfg.primitives).start(obs)

    flipped: set[tuple[tuple, int]] = set()
    for n, m in zip(coo.row, coo.col, strict=True):
        a, b = cells[int(n)], cells[int(m)]
        if a[0] == b[0]:
            assert sum(x != y for x, y in zip(a, b, strict=True)) == 1  # one step of one axis
            continue
        assert a[4:] == b[4:]  # the pose does not change
        fa, fb = g.postures[a[0]].faces, g.postures[b[0]].faces
        (f,) = [i for i in range(3) if fa[i] != fb[i]]
        assert f in (0, 2)
        stay = [i for i in range(3) if i != f]
        assert fa[stay[0]] != fa[stay[1]] and all(a[1 + j] == b[1 + j] for j in stay)
        flipped.add((a, f))
    assert len(flipped) > 20
    rng = np.random.default_rng(0)
    some = sorted(flipped)
    for k in rng.choice(len(some), 20, replace=False):
        assert flip_refuses(*some[k]) is None, some[k]

    def lands(cell: tuple, f: int) -> bool:  # some node of the flipped posture to go to
        faces = list(g.postures[cell[0]].faces)
        faces[f] = Face.LEFT if faces[f] == Face.RIGHT else Face.RIGHT
        if Posture(tuple(faces)) not in g.postures:
            return False
        index = [g.postures.index(Posture(tuple(faces))), *cell[1:]]
        index[1 + f] = slice(None)
        return bool((g.ids[tuple(index)] >= 0).any())

    refused = [(cell, f) for cell in cells.values() for f in (0, 2)
               if (cell, f) not in flipped and lands(cell, f)
               and len({g.postures[cell[0]].faces[j] for j in range(3) if j != f}) == 2]
    assert len(refused) > 20
    pairs_hold = 0
    for k in rng.choice(len(refused), 40, replace=False):
        assert flip_refuses(*refused[k]) is not None, refused[k]
        pairs_hold += holds_alone(*refused[k])
    assert 0 < pairs_hold < 40  # both reasons occur


def test_a_flip_finds_its_way_round_the_end_only_with_the_pole_held_high():
    """``way_table``: with an upright pole whose lower end is a few centimetres above the palm
    no finger passes under it; held high, some lifts reach some hovers, for both fingers."""
    from inhand_exp.task.graph import way_table

    model = HandModel.from_config(HandConfig(), ObjectConfig(), 9.81)
    cs = np.linspace(-0.2, 0.2, 9)  # the pole's faces, 5 cm apart
    for z, some in ((0.30, False), (0.44, True)):
        lat = Lattice(np.array([-0.02, 0.0, 0.02]), np.array([z]), np.array([-0.2, 0.0, 0.2]),
                      cs)
        for finger in (0, 2):
            assert way_table(model, lat, finger).any() == some, (z, finger)


def test_slide_edges_follow_the_slides_own_force_check(compose_cfg):
    """``slide_table`` gives the verdict of ``Slide.start``'s force check (the other two
    fingers hold the weight and the sliding finger's drag), over random held grasps of the
    whole workspace, both ways along the face."""
    from inhand_exp.config import PrimitivesConfig, TaskConfig, typed
    from inhand_exp.control.execute import Observation
    from inhand_exp.control.sample import random_grasp
    from inhand_exp.control.slide import Slide
    from inhand_exp.task.graph import SLIDE_SIGNS, slide_table

    cfg = compose_cfg("learner=search", "mode=eval")
    model = HandModel.from_config(cfg.hand, cfg.object, cfg.sim.gravity_mps2)
    prim = typed(cfg.primitives, PrimitivesConfig)
    workspace = Workspace.from_config(typed(cfg.task, TaskConfig))
    rng = np.random.default_rng(7)
    force = ("cannot hold the object while", "would have to press")
    verdicts = {True: 0, False: 0}
    for _ in range(30):
        pose, contacts, q = random_grasp(model, rng, workspace, press=0.0)
        lat = Lattice(np.zeros(1), np.zeros(1), np.array([pose[2]]), np.array(contacts.coords))
        holds = np.zeros((3, 3, 3), dtype=bool)
        holds[0, 1, 2] = True
        for finger in range(3):
            table = slide_table(model, lat, contacts.posture, finger, prim, holds)
            for d, sign in enumerate(SLIDE_SIGNS):
                slides = bool(table[d, 0, 1, 2, 0])
                obs = Observation(q, np.zeros(6), pose, np.zeros(3), 0.0)
                why = Slide(model, contacts, finger, sign * 0.02, 0.5, prim).start(obs)
                if why is None or any(w in why for w in force):
                    assert slides == (why is None), (pose, contacts, finger, sign, why)
                    verdicts[slides] += 1
    assert verdicts[True] >= 20 and verdicts[False] >= 20, verdicts


def test_an_upright_poles_lone_finger_has_no_slide_edge_down(compose_cfg, tmp_path):
    """Within 0.2 rad of upright, slides of the lone finger go up the pole only; the others
    go both ways (the pole held lower than in TINY, where the lone finger slides up too)."""
    from inhand_exp.control.sample import lone_finger

    low = [o.replace("[0.40,0.44]", "[0.32,0.36]") for o in TINY]
    search = Search(compose_cfg(*low, f"learner.cache_dir={tmp_path}"))
    g = search.ensure_graph()
    cells = {int(n): tuple(ix) for ix, n in np.ndenumerate(g.ids) if n >= 0}
    coo = g.matrix.tocoo()
    ways = {(lone, up): 0 for lone in (True, False) for up in (True, False)}
    for n, m in zip(coo.row, coo.col, strict=True):
        a, b = cells[int(n)], cells[int(m)]
        if a[0] != b[0] or a[4:] != b[4:]:
            continue  # a flip or a repose
        (f,) = [i for i in range(3) if a[1 + i] != b[1 + i]]
        lone = f == lone_finger(g.postures[a[0]])
        ways[lone, bool(b[1 + f] > a[1 + f])] += 1  # the coordinate grows up the pole
    assert ways[True, False] == 0, ways
    assert min(ways[True, True], ways[False, True], ways[False, False]) > 0, ways


def test_the_graph_holds_only_grasps_the_primitives_may_move(compose_cfg, tiny_graph_dir):
    """A node's contacts have the slack a repose asks of the grasp it moves
    (``primitives.min_grasp_margin``): asking for more slack leaves fewer nodes, all firm."""
    from inhand_exp.config import PrimitivesConfig, typed
    from inhand_exp.control.repose import strict_hold

    def graph(margin: float) -> tuple[Search, PoseGraph]:
        search = Search(compose_cfg(*TINY, f"learner.cache_dir={tiny_graph_dir}",
                                    f"primitives.min_grasp_margin={margin}"))
        return search, search.ensure_graph()

    _, loose = graph(0.02)  # the default: the TINY graph the other tests read
    search, firm = graph(0.1)
    assert 0 < firm.matrix.shape[0] < loose.matrix.shape[0]
    prim = typed(search.cfg.primitives, PrimitivesConfig)
    for p, *k in {(ix[0], *ix[1:4]) for ix, n in np.ndenumerate(firm.ids) if n >= 0}:
        contacts = Contacts(firm.postures[p], tuple(float(firm.lattice.cs[j]) for j in k))
        assert strict_hold(search.model, contacts, prim, firm=True), contacts
