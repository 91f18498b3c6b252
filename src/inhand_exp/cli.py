"""Thin entry points: ``inhand-exp`` (the Hydra app).

``inhand-exp resume=RUN_DIR [overrides]`` continues an interrupted training: it re-composes the
run's own overrides (``RUN_DIR/.hydra/overrides.yaml``) followed by the new ones, writes into
``RUN_DIR`` without touching what is there (a new ``run-2.mcap``...), and trains from
``RUN_DIR/policy.pt`` up to ``train.frames``.
"""

from __future__ import annotations

import json
import signal
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.experimental.callback import Callback
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

from inhand_exp.config import ConfigError, register_configs, validate
from inhand_exp.errors import CheckpointError, DemonstrationsError, GoalsError
from inhand_exp.policies import resolve
from inhand_exp.runinfo import CONF_DIR

register_configs()


def fresh_log_path(run_dir: Path, name: str) -> Path:
    """``run_dir/name``, or ``run-2.mcap``, ``run-3.mcap``... if taken: nothing is overwritten."""
    path, k = run_dir / name, 2
    while path.exists():
        path = run_dir / f"{Path(name).stem}-{k}{Path(name).suffix}"
        k += 1
    return path


def run(cfg: DictConfig, run_dir: Path, overrides: list[str]) -> Path:
    """Validate ``cfg``, open the run log in ``run_dir`` and do what ``cfg.mode`` asks."""
    validate(cfg)
    cfg.checkpoint = resolve(cfg.checkpoint)  # packaged:NAME -> the packaged policy's file
    for what, name in (("checkpoint", cfg.checkpoint), ("goal file", cfg.eval.goals_file)):
        if name and not Path(name).is_file():  # before anything is written
            raise FileNotFoundError(f"{what} {name} not found")
    done = run_dir / DONE
    if done.is_file() and not cfg.resume:
        earlier = _done_overrides(done)
        if earlier is not None and sorted(earlier) != sorted(overrides):
            raise ConfigError(f"{run_dir} holds a finished run of other settings "
                              f"({' '.join(earlier) or 'no overrides'}); give this one another "
                              f"directory (hydra.run.dir, hydra.sweep.dir) or remove that one")
        print(f"{run_dir}: finished earlier ({done}); skipped")
        return run_dir / cfg.log.file
    # torch, TorchRL and PyBullet only now: the refusals and skips above answer within a second
    from inhand_exp.experiment import prepare, run_job
    from inhand_exp.learn.registry import LEARNERS
    from inhand_exp.record import RunLog
    from inhand_exp.runinfo import run_config_message

    if cfg.learner.name not in LEARNERS:
        raise ConfigError(f"learner={cfg.learner.name} is not built yet; known learners: "
                          f"{', '.join(sorted(LEARNERS))}")

    # every input read and checked: a refusal writes nothing
    job = prepare(cfg, run_dir, overrides)
    log_path = run_dir / cfg.log.file
    if cfg.resume:
        log_path = fresh_log_path(run_dir, cfg.log.file)
    elif log_path.exists():  # an interrupted attempt: its files are kept beside the new ones
        kept = []
        for old in (log_path, run_dir / "goals.csv"):
            if old.exists():
                aside = fresh_log_path(run_dir, f"{old.stem}-interrupted{old.suffix}")
                old.rename(aside)
                kept.append(aside.name)
        print(f"{run_dir}: an earlier attempt did not finish; kept as {', '.join(kept)}")
    with RunLog(log_path, chunk_size=cfg.log.chunk_size_bytes,
                flush_every_s=cfg.log.flush_every_s) as log:
        log.write("/run/config", run_config_message(
            cfg, run_dir, overrides, job.learner.trained_with if job.learner else None))
        log.flush()
        summary = run_job(cfg, run_dir, log, job)
    done.write_text(json.dumps({"log": log_path.name, "overrides": list(overrides),
                                "summary": summary}, default=float) + "\n")
    if str(cfg.mode) == "demo" and cfg.log.sim_state_hz > 0:
        from inhand_exp.analysis.render import RenderError, render

        try:
            gif = render(log_path, first_success(log_path))
            print(f"one hard episode replayed in {gif} (inhand-render {log_path} --episode N "
                  f"for another)")
        except RenderError as err:
            print(f"inhand-exp: no replay: {err}", file=sys.stderr)
    return log_path


def first_success(log_path: Path) -> int | None:
    """The first successful hard episode of a demo log (None: the first with states)."""
    from inhand_exp.record import read_log

    for m in read_log(log_path, topics=("/eval/episode",)).topic("/eval/episode"):
        if m["group"] == "hard" and m["success"]:
            return m["episode"]
    return None


def resume_argv(argv: list[str]) -> list[str]:
    """Turn ``resume=RUN_DIR [overrides]`` into the run's overrides + the new ones.

    Checked before Hydra runs, so a bad directory writes nothing.
    """
    given = [a for a in argv if a.startswith("resume=")]
    if not given:
        return argv
    if any(a in ("-m", "--multirun") or a.startswith("hydra/launcher") for a in argv):
        raise ConfigError("resume= continues one run; it cannot be combined with --multirun")
    run_dir = Path(given[-1].split("=", 1)[1]).expanduser().resolve()
    saved = run_dir / ".hydra" / "overrides.yaml"
    if not saved.is_file():
        raise FileNotFoundError(f"resume={run_dir}: not a run directory of inhand-exp "
                                f"({saved} not found)")
    if not (run_dir / "policy.pt").is_file():
        raise FileNotFoundError(f"resume={run_dir}: no policy.pt there (the run stopped before "
                                f"its first checkpoint); start it again instead")
    before = [o for o in OmegaConf.load(saved)
              if not o.startswith(("resume=", "hydra.run.dir=", "checkpoint="))]
    rest = [a for a in argv if not a.startswith("resume=")]
    return [*before, *rest, f"resume={run_dir}", f"hydra.run.dir={run_dir}",
            "hydra.output_subdir=null"]


class Interrupted(KeyboardInterrupt):
    """A SIGTERM (``kill``, a scheduler's time limit) raised in the main thread, so that it
    stops a run as Ctrl-C does: the log is closed and the environment workers are shut down."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _raise_interrupted(signum: int, frame) -> None:
    raise Interrupted(signum)


def interrupt_behind(err: BaseException) -> KeyboardInterrupt | None:
    """The Ctrl-C or SIGTERM that ``err`` was raised while handling, if any: a signal that lands
    inside a library's code (OmegaConf building a config, say) can leave it half-done, and the
    error the library raises next is the interrupt's doing, not a failure of the run."""
    seen: set[int] = set()
    while err is not None and id(err) not in seen:
        if isinstance(err, KeyboardInterrupt):
            return err
        seen.add(id(err))
        err = err.__context__ or err.__cause__
    return None


def _stopped(err: KeyboardInterrupt, cfg: DictConfig, run_dir: Path, in_sweep: bool) -> None:
    signum = getattr(err, "signum", signal.SIGINT)
    print(f"\n{interrupted_note(cfg, run_dir, signum, in_sweep)}", file=sys.stderr)
    raise SystemExit(128 + signum) from None


def interrupted_note(cfg: DictConfig, run_dir: Path, signum: int, in_sweep: bool) -> str:
    """What a run stopped by ``signum`` left in ``run_dir``, and the command that goes on."""
    from inhand_exp.learn.checkpoint import read_checkpoint

    head = (f"inhand-exp: stopped by {signal.Signals(signum).name}; {run_dir} keeps the log "
            f"written so far")
    if in_sweep:
        return f"{head}. Run the sweep again to go on: it skips the jobs that finished."
    if str(getattr(cfg.mode, "value", cfg.mode)) not in ("train", "train_eval"):
        return f"{head} (inhand-analyze reads it). Run the command again to start over."
    if cfg.train.store:
        return (f"{head}. Run the command again: the training goes on from its last "
                f"checkpoint in {cfg.train.store}.")
    path = run_dir / "policy.pt"
    try:
        state = read_checkpoint(path, cfg.learner.name)
    except (FileNotFoundError, CheckpointError):
        return f"{head}; no policy was saved yet. Run the command again to start over."
    frames, total = int(state["frames"]), int(cfg.train.frames)
    saved = f"{path} holds iteration {state['iteration']} ({frames:,} frames)"
    if cfg.checkpoint:  # trained on from another policy: train.frames more than it had
        total += int(read_checkpoint(Path(cfg.checkpoint), cfg.learner.name)["frames"])
        if frames < total:
            return (f"{head}; {saved} of {total:,}. Train on from it with: inhand-exp "
                    f"mode={cfg.mode} checkpoint={path} train.frames={total - frames}")
    if frames >= total:  # the training finished; its evaluation was cut
        return (f"{head}; {saved}, the whole training. Evaluate it with: inhand-exp "
                f"mode=eval checkpoint={path}")
    return f"{head}; {saved} of {total:,}. Continue with: inhand-exp resume={run_dir}"


DONE = "done.json"  # written when a run finishes: a sweep run again skips it
FAILED = "failed.txt"  # written when a job of a sweep fails, with its error
REFUSED = 2  # the exit code of every refused input (bad config value, file, checkpoint)
_started = False  # the job function was entered: Hydra composed the config


def _done_overrides(done: Path) -> list[str] | None:
    """The overrides a finished run recorded in its ``done.json`` (None: not recorded)."""
    try:
        recorded = json.loads(done.read_text()).get("overrides")
    except (OSError, ValueError, AttributeError):
        return None
    return [str(o) for o in recorded] if isinstance(recorded, list) else None


def check_choices(choices) -> None:
    """Refuse ``group=schema``: ``--help`` lists each group's typed schema beside its options,
    but a schema alone is no option (it would run on its defaults without a word)."""
    for group, option in choices.items():
        if isinstance(option, str) and option.startswith("schema") and "/" not in group:
            raise ConfigError(f"{group}={option} is the typed schema of the group, not an "
                              f"option; see `inhand-exp --help` for the options of '{group}'")


def _discard(run_dir: Path) -> None:
    """Remove the run directory Hydra made for a refused run, if it holds only Hydra's own
    files (``.hydra/``, ``*.log``): a refused run leaves nothing behind, and nothing else is
    ever deleted."""
    if not run_dir.is_dir():
        return
    entries = list(run_dir.iterdir())
    if all(e.name == ".hydra" or (e.is_file() and e.suffix == ".log") for e in entries):
        for e in entries:
            if e.is_dir():
                for f in e.iterdir():
                    f.unlink()
                e.rmdir()
            else:
                e.unlink()
        run_dir.rmdir()


class FailureReport(Callback):
    """At the end of a sweep: name every job that failed, with its error, and exit 1.

    A job of a sweep that fails (a refused input, or an error on the way) writes ``failed.txt``
    into its directory and ends; the sweep goes on with the other jobs, whatever the launcher.
    """

    def on_multirun_end(self, config: DictConfig, **kwargs) -> None:
        sweep = Path(config.hydra.sweep.dir)
        failed = sorted(sweep.rglob(FAILED)) if sweep.is_dir() else []
        if not failed:
            return
        print(f"inhand-exp: {len(failed)} job(s) of the sweep in {sweep} failed:",
              file=sys.stderr)
        for path in failed:
            first = path.read_text().strip().splitlines()[0]
            print(f"  {path.parent.relative_to(sweep)}: {first}", file=sys.stderr)
        global _started
        _started = True  # Hydra composed and ran: this exit is not a refused command line
        raise SystemExit(1)


def _fail_job(run_dir: Path, err: BaseException, refused: bool) -> None:
    """Record a sweep job's failure in its directory (the sweep goes on without it)."""
    import traceback

    run_dir.mkdir(parents=True, exist_ok=True)
    text = f"{type(err).__name__}: {err}" if not refused else str(err)
    detail = "" if refused else "\n" + "".join(traceback.format_exception(err))
    (run_dir / FAILED).write_text(text.splitlines()[0] + "\n" + detail)
    print(f"inhand-exp: job {run_dir} failed: {text.splitlines()[0]}", file=sys.stderr)


@hydra.main(version_base="1.3", config_path=str(CONF_DIR), config_name="config")
def _app(cfg: DictConfig) -> None:
    global _started
    _started = True
    hc = HydraConfig.get()
    run_dir = Path(hc.runtime.output_dir)
    in_sweep = hc.mode == RunMode.MULTIRUN
    (run_dir / FAILED).unlink(missing_ok=True)  # a job run again starts with a clean slate
    try:
        check_choices(hc.runtime.choices)
        log_path = run(cfg, run_dir, list(hc.overrides.task))
    except (ConfigError, CheckpointError, DemonstrationsError, GoalsError,
            FileNotFoundError) as err:
        if (stop := interrupt_behind(err)) is not None:
            _stopped(stop, cfg, run_dir, in_sweep)
        if in_sweep:
            _fail_job(run_dir, err, refused=True)
            return
        print(f"inhand-exp: {err}", file=sys.stderr)
        if not cfg.get("resume"):
            _discard(run_dir)
        raise SystemExit(REFUSED) from None
    except KeyboardInterrupt as err:  # Ctrl-C, or SIGTERM (``Interrupted``): stops a sweep too
        _stopped(err, cfg, run_dir, in_sweep)
    except Exception as err:  # noqa: BLE001 - a sweep outlives one job's error
        if (stop := interrupt_behind(err)) is not None:
            _stopped(stop, cfg, run_dir, in_sweep)
        if not in_sweep:
            raise
        _fail_job(run_dir, err, refused=False)
        return
    print(f"run written to {log_path.parent}  (log: {log_path})")


def main() -> None:
    if not (CONF_DIR / "config.yaml").is_file():
        sys.exit(f"inhand-exp: config tree not found at {CONF_DIR}; "
                 "install from a source checkout with `pip install -e .`")
    signal.signal(signal.SIGTERM, _raise_interrupted)
    try:
        sys.argv[1:] = resume_argv(sys.argv[1:])
    except (ConfigError, FileNotFoundError) as err:
        print(f"inhand-exp: {err}", file=sys.stderr)
        raise SystemExit(REFUSED) from None
    try:
        _app()
    except SystemExit as end:
        if end.code == 1 and not _started:  # Hydra refused the command line (its message is out)
            raise SystemExit(REFUSED) from None
        raise
