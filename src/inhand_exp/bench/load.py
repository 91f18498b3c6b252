"""``inhand-bench load --minutes M``: a long run of the training layout under a random policy,
sampling the memory (RSS) and open file descriptors of this process and its environment workers
over time, to show that they hold steady (no leak of worlds, pipes or shared memory)."""

from __future__ import annotations

import multiprocessing
import os
import time
from pathlib import Path

import torch
from omegaconf import DictConfig

from inhand_exp.envs.batched import batched_env


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


def _fds(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


def sample() -> tuple[float, int, int]:
    """RSS (MB) and open descriptors of this process and its live children, and the children."""
    pids = [os.getpid(), *(p.pid for p in multiprocessing.active_children())]
    rss, fds = 0.0, 0
    for pid in pids:
        try:
            rss, fds = rss + _rss_mb(pid), fds + _fds(pid)
        except (FileNotFoundError, ProcessLookupError):  # a child that just ended
            continue
    return rss, fds, len(pids) - 1


def load_run(cfg: DictConfig, minutes: float, every_s: float, seed: int) -> dict:
    env = batched_env(cfg, seed)
    gen = torch.Generator().manual_seed(seed)
    rows, actions = [], 0
    try:
        td = env.reset()
        start = last = time.perf_counter()
        rows.append((0.0, *sample(), 0))
        while time.perf_counter() - start < minutes * 60:
            mask = td["action_mask"].reshape(-1, td["action_mask"].shape[-1]).float()
            td.set("action", torch.multinomial(mask, 1, generator=gen).reshape(td.shape))
            td, root = env.step_and_maybe_reset(td)
            actions += td.numel()
            td = root
            if time.perf_counter() - last >= every_s:
                last = time.perf_counter()
                row = (last - start, *sample(), actions)
                rows.append(row)
                print(f"{row[0]:7.0f} s  RSS {row[1]:8.1f} MB  fds {row[2]:4d}  workers "
                      f"{row[3]}  actions {row[4]}", flush=True)
    finally:
        env.close()
    rss = [r[1] for r in rows]
    fds = [r[2] for r in rows]
    half = len(rows) // 2
    return {"minutes": minutes, "envs": cfg.train.num_envs, "workers": cfg.train.workers,
            "actions": actions, "samples": len(rows), "rss_mb_first": rss[0],
            "rss_mb_last": rss[-1], "rss_mb_max": max(rss),
            "rss_mb_growth_second_half": rss[-1] - rss[half] if half else 0.0,
            "fds_first": fds[0], "fds_last": fds[-1], "fds_max": max(fds)}
