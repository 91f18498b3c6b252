"""Many environments at once: ``workers`` processes, each stepping a ``SerialEnv``.

The environments are mid-level ``PrimitiveEnv`` by default, or any class built as
``cls(cfg, goals=..., states_hz=..., once=...)`` (the end-to-end ``TorqueEnv``).

The batch has shape ``(workers, num_envs // workers)``. The ``parallel`` backend runs each row in
its own process (``ParallelEnv``); ``serial`` runs everything in this process, with the same
layout, so both give the same numbers for the same seed. One seed seeds the whole batch; the
sub-environments get the seeds TorchRL derives from it, in row-major order.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
import time
import warnings
from contextlib import contextmanager

from omegaconf import DictConfig, OmegaConf
from torchrl.envs import EnvBase, ParallelEnv, SerialEnv

from inhand_exp.config import ConfigError, SearchConfig
from inhand_exp.envs.primitive_env import PrimitiveEnv
from inhand_exp.task.goals import GoalPair
from inhand_exp.task.graph import cached_graph


class SleepyParallelEnv(ParallelEnv):
    """``ParallelEnv`` whose main process sleeps while its workers step.

    TorchRL 0.14 waits for the workers by spinning on shared-memory flags, which keeps a whole
    core busy; on a 2-core machine that core is taken from the two workers. A mid-level step
    lasts tens of milliseconds, so polling every ``poll_s`` costs nothing measurable. Once every
    flag is up (or a worker died, or the time limit passed) TorchRL's own wait takes over: it
    clears the flags and reports dead workers and timeouts as usual.
    """

    poll_s = 0.0005

    def _wait_for_workers(self, workers_range):
        flags = getattr(self, "_shm_done_flags", None)
        if self._use_buffers and flags is not None:
            index = self._worker_indices
            start = last_check = time.monotonic()
            while not all(flags[index[i]] for i in workers_range):
                time.sleep(self.poll_s)
                now = time.monotonic()
                if now - last_check > 1.0:
                    last_check = now
                    if (now - start > self.BATCHED_PIPE_TIMEOUT
                            or not all(self._workers[i].is_alive() for i in workers_range)):
                        break
        return super()._wait_for_workers(workers_range)


class Row(SerialEnv):
    """One worker's environments. TorchRL starts them at their first reset, and its worker
    closes them when told to: a run stopped before that first reset (Ctrl-C right after the
    workers came up) closes a row that never started, which TorchRL would refuse with an
    error of the worker's own."""

    def close(self, *, raise_if_closed: bool = True) -> None:
        super().close(raise_if_closed=False)


@contextmanager
def signals_held(*signums: int):
    """Run the block with ``signums`` noted instead of handled, then hand the first one that
    came to its own handler. Python runs signal handlers in the main thread only: elsewhere
    the block runs as it is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    came: list[int] = []
    before = {s: signal.signal(s, lambda signum, frame: came.append(signum)) for s in signums}
    try:
        yield
    finally:
        for s, handler in before.items():
            signal.signal(s, handler)
        if came:
            signal.raise_signal(came[0])


def _make_env(cfg: dict, goals: list[GoalPair] | None = None, states_hz: float = 0.0,
              once: bool = False, env_class: type[EnvBase] = PrimitiveEnv) -> EnvBase:
    return env_class(OmegaConf.create(cfg), goals=goals, states_hz=states_hz, once=once)


def _make_row(cfg: dict, goals: list[list[GoalPair]] | None, per: int,
              states_hz: float, once: bool = False,
              env_class: type[EnvBase] = PrimitiveEnv, owner: int | None = None) -> Row:
    if owner is not None and os.getpid() != owner:
        # In a worker process (TorchRL also builds a row in the main process, for its specs:
        # that one keeps its signals). Ctrl-C reaches every process of the terminal's group,
        # and a scheduler's SIGTERM every process of the job: the main process stops the run
        # and closes its workers itself, so a worker leaves both to it instead of dying
        # mid-step with a traceback of its own (one whose main process is gone ends as its
        # pipe closes).
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    kwargs = [{"cfg": cfg, "states_hz": states_hz, "once": once, "env_class": env_class,
               "goals": None if goals is None else goals[j]} for j in range(per)]
    return Row(per, _make_env, create_env_kwargs=kwargs)


def layout(cfg: DictConfig, num_envs: int | None = None) -> tuple[int, int]:
    """(worker processes, environments per worker) for ``cfg.train``.

    Workers are capped at the core count and lowered until they split the environments evenly,
    with a warning.
    """
    n = cfg.train.num_envs if num_envs is None else num_envs
    cores = os.cpu_count() or 1
    asked = min(cfg.train.workers, n)
    workers = min(asked, cores)
    while n % workers:  # rows of equal length
        workers -= 1
    if workers != asked:
        warnings.warn(f"train.workers={cfg.train.workers} with {n} environments on {cores} "
                      f"cores: using {workers} worker processes", stacklevel=2)
    return workers, n // workers


def split_goals(goals: list[GoalPair], n: int) -> list[list[GoalPair]]:
    """Deal ``goals`` round-robin to ``n`` environments: environment ``i`` gets i, i+n, ..."""
    if len(goals) < n:
        raise ConfigError(f"{len(goals)} goal pairs cannot feed {n} environments; "
                          f"lower train.num_envs")
    return [goals[i::n] for i in range(n)]


def plain_start_method() -> None:
    """Make this process's default start method a standard one before spawning workers.

    Inside a job of Hydra's joblib launcher the default is joblib's own ``loky``, and a spawned
    child copies the parent's default as it starts: it cannot find ``loky`` and dies ("cannot
    find context for 'loky'"). The workers are spawned explicitly anyway.
    """
    if multiprocessing.get_start_method(allow_none=True) not in (None, "spawn", "fork",
                                                                  "forkserver"):
        multiprocessing.set_start_method("spawn", force=True)


def batched_env(cfg: DictConfig, seed: int, goals: list[GoalPair] | None = None,
                num_envs: int | None = None, states_hz: float = 0.0,
                once: bool = False, env_class: type[EnvBase] = PrimitiveEnv) -> EnvBase:
    """The batched ``env_class`` environment for ``cfg`` (``train.backend``), seeded with
    ``seed``.

    ``goals``: a fixed goal set, dealt round-robin over the environments (see ``split_goals``);
    without it every episode draws a training pair. ``once``: each environment idles after its
    share of the goals (evaluation).
    """
    workers, per = layout(cfg, num_envs)
    if cfg.task.reward_route > 0 and env_class is PrimitiveEnv:
        # built here once, read by every worker
        cached_graph(cfg, SearchConfig(cache_dir=cfg.task.route_cache_dir))
    plain = OmegaConf.to_container(cfg, resolve=True, enum_to_str=True)
    rows = [None] * workers
    if goals is not None:
        dealt = split_goals(goals, workers * per)
        rows = [dealt[w * per:(w + 1) * per] for w in range(workers)]
    backend = str(getattr(cfg.train.backend, "value", cfg.train.backend))
    owner = None if backend == "serial" else os.getpid()
    kwargs = [{"cfg": plain, "goals": rows[w], "per": per, "states_hz": states_hz,
               "once": once, "env_class": env_class, "owner": owner} for w in range(workers)]
    # A Ctrl-C or SIGTERM while the batch is built (TorchRL builds one environment in this
    # process to read its specs, then starts the workers at set_seed) waits until it is built,
    # then stops the run with the batch closed. Landing inside OmegaConf or PyBullet half-way,
    # it would leave their objects half-built and end the run with their error; landing while
    # the workers are spawned, it would leave a child reading its start-up data after the main
    # process let it go, with a traceback of the child's own. (A Ctrl-C still reaches a child
    # that is importing its modules then; it ignores the signal only from ``_make_row`` on.)
    env = None
    try:
        with signals_held(signal.SIGINT, signal.SIGTERM):
            if backend == "serial":
                env = SerialEnv(workers, _make_row, create_env_kwargs=kwargs)
            else:
                plain_start_method()
                env = SleepyParallelEnv(workers, _make_row, create_env_kwargs=kwargs,
                                        mp_start_method="spawn")
            env.set_seed(seed)
    except KeyboardInterrupt:
        if env is not None and not env.is_closed:
            env.close()
        raise
    return env
