"""``inhand-bench graph``: the search baseline's graph at the configured resolutions, built fresh
(no cache): nodes, edges, build time, memory, and the time of one Dijkstra query."""

from __future__ import annotations

import resource
import time

import numpy as np
from omegaconf import DictConfig

from inhand_exp.config import PrimitivesConfig, SearchConfig, TaskConfig, typed
from inhand_exp.control.hand import HandModel
from inhand_exp.control.sample import Workspace
from inhand_exp.task.graph import build_graph


def graph_size(cfg: DictConfig, queries: int = 20, seed: int = 0) -> dict:
    s = typed(cfg.learner, SearchConfig)
    rules = typed(cfg.task, TaskConfig)
    model = HandModel.from_config(cfg.hand, cfg.object, cfg.sim.gravity_mps2)
    workspace = Workspace.from_config(rules)
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    g = build_graph(model, typed(cfg.primitives, PrimitivesConfig), workspace, s.resolution_m,
                    s.resolution_rad, s.contact_resolution_m)
    peak = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0) / 1e3  # kB -> MB
    rng = np.random.default_rng(seed)
    goals = [workspace.draw(rng) for _ in range(queries)]
    t = time.perf_counter()
    fields = [g.distances_to(goal) for goal in goals]
    query = (time.perf_counter() - t) / queries
    held = [d for d in fields if np.isfinite(d).any()]  # goal cells that hold a node
    reach = [float(np.isfinite(d).mean()) for d in held] or [0.0]
    cells = int(np.prod(g.ids.shape))
    print(f"resolution {s.resolution_m * 100:g} cm, {s.resolution_rad:g} rad, contacts "
          f"{s.contact_resolution_m * 100:g} cm: {cells:,} cells, {g.nodes:,} nodes, "
          f"{g.edges:,} edges")
    print(f"build {g.build_s:.1f} s, graph {g.bytes / 1e6:.1f} MB, peak RSS growth {peak:.0f} MB, "
          f"Dijkstra query {query * 1e3:.1f} ms (mean over {queries} random goals; {len(held)} "
          f"of them in a held cell, reached from {np.mean(reach):.1%} of the nodes)")
    return {"resolution_m": s.resolution_m, "resolution_rad": s.resolution_rad,
            "contact_resolution_m": s.contact_resolution_m, "cells": cells, "nodes": g.nodes,
            "edges": g.edges, "build_s": g.build_s, "graph_mb": g.bytes / 1e6,
            "peak_rss_growth_mb": peak, "query_s": query, "reach_fraction": float(np.mean(reach))}
