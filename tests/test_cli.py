"""The ``inhand-exp`` app end to end: run layout, the /run/config log, errors, multirun."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import torch

from inhand_exp.record import read_log
from inhand_exp.task.goals import load_goals

APP = [sys.executable, "-c", "from inhand_exp.cli import main; main()"]
SWEEPS = Path(__file__).resolve().parents[1] / "sweeps"
# a tiny training and evaluation budget: the CLI runs end to end in seconds
FAST = ["train.frames=8", "learner.frames_per_batch=8", "learner.minibatch_size=4",
        "train.num_envs=2", "train.backend=serial",
        "learner.epochs=1", "eval.episodes=1", "task.max_actions=2"]


def inhand_exp(*args: str, cwd: Path, fast: bool = True) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "HYDRA_FULL_ERROR": "0"}
    # mode=train_eval first: the tests train tiny policies (the default, demo, is tested apart;
    # a resumed run takes its mode from the run it resumes)
    flags = [a for a in args if a in ("-m", "--multirun")]  # before the overrides
    rest = [a for a in args if a not in flags]
    first = [] if any(a.startswith("resume=") for a in args) else ["mode=train_eval"]
    return subprocess.run([*APP, *flags, *first, *rest, *(FAST if fast else [])], cwd=cwd,
                          env=env, capture_output=True, text=True, timeout=300)


def run_config(path: Path) -> dict:
    log = read_log(path)
    assert not log.truncated and log.corrupt_chunks == 0
    (msg,) = log.topic("/run/config")
    return msg


def test_default_run_goes_under_logs_runs_date_time(tmp_path):
    res = inhand_exp("seed=7", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    (log_path,) = tmp_path.glob("logs/runs/*/*/run.mcap")
    date, time = log_path.parent.parent.name, log_path.parent.name
    assert len(date) == 10 and date[4] == "-" and len(time) == 8
    assert str(log_path.parent) in res.stdout
    assert (log_path.parent / ".hydra" / "config.yaml").is_file()
    msg = run_config(log_path)
    assert msg["seed"] == 7 and msg["config"]["seed"] == 7
    assert msg["config"]["object"]["name"] == "pole"
    assert msg["versions"]["torch"].startswith("2.13")
    assert msg["overrides"] == ["mode=train_eval", "seed=7", *FAST]
    log = read_log(log_path)
    assert [m["iteration"] for m in log.topic("/train/iteration")] == [1]
    (episode,) = log.topic("/eval/episode")
    assert {"group", "success", "dropped", "timeout", "sim_time_s", "n_actions", "x0", "xg",
            "final_pose"} <= set(episode)
    assert (log_path.parent / "policy.pt").is_file() and (log_path.parent / "goals.csv").is_file()
    assert "ours" in res.stdout and "paper" in res.stdout


def test_config_error_exits_before_writing_a_log(tmp_path):
    res = inhand_exp("object.mass_kg=-1", f"hydra.run.dir={tmp_path / 'run'}", cwd=tmp_path)
    assert res.returncode == 2
    assert "object.mass_kg must be > 0, got -1.0" in res.stderr
    assert "Traceback" not in res.stderr
    assert not (tmp_path / "run" / "run.mcap").exists()


def test_typo_exits_naming_the_key(tmp_path):
    res = inhand_exp("object.mas_kg=1", f"hydra.run.dir={tmp_path / 'run'}", cwd=tmp_path)
    assert res.returncode != 0
    assert "object.mas_kg" in res.stderr


def test_existing_log_is_never_overwritten(tmp_path):
    run_dir = tmp_path / "run"
    first = inhand_exp(f"hydra.run.dir={run_dir}", cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    before = (run_dir / "run.mcap").read_bytes()
    second = inhand_exp(f"hydra.run.dir={run_dir}", cwd=tmp_path)
    assert second.returncode == 0 and "finished earlier" in second.stdout  # skipped
    assert (run_dir / "run.mcap").read_bytes() == before
    other = inhand_exp(f"hydra.run.dir={run_dir}", "eval.episodes=3", cwd=tmp_path)
    assert other.returncode == 2  # not skipped as if it were the same job
    assert f"{run_dir} holds a finished run of other settings" in other.stderr
    assert (run_dir / "run.mcap").read_bytes() == before


JOBLIB = ["hydra/launcher=joblib", "hydra.launcher.n_jobs=2"]


@pytest.mark.parametrize("launcher", [[], JOBLIB, [*JOBLIB, "train.backend=parallel"],
                                      ["hydra/launcher=submitit_local"]],
                         ids=["basic", "joblib", "joblib-worker-processes", "submitit-local"])
def test_two_job_multirun_leaves_two_readable_logs(tmp_path, launcher):
    """Under joblib, jobs whose environments run in worker processes work too (joblib's
    'loky' start method must not reach the spawned workers)."""
    sweep = tmp_path / "sweep"
    args = ["-m", "seed=0,1", f"hydra.sweep.dir={sweep}", *FAST, *launcher]
    res = inhand_exp(*args, cwd=tmp_path, fast=False)
    assert res.returncode == 0, res.stderr
    seeds = sorted(run_config(sweep / job / "run.mcap")["seed"] for job in ("0", "1"))
    assert seeds == [0, 1]


def test_multirun_default_layout(tmp_path):
    res = inhand_exp("-m", "goals=easy,hard", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    logs = sorted(tmp_path.glob("logs/multirun/*/*/*/run.mcap"))
    assert [p.parent.name for p in logs] == ["0", "1"]
    assert [run_config(p)["config"]["goals"]["name"] for p in logs] == ["easy", "hard"]


def bad_goal_files(tmp_path: Path) -> dict[str, Path]:
    """A header alone, and one good pair moved so that its start, or its goal, is out of reach."""
    from inhand_exp.config import HandConfig, ObjectConfig
    from inhand_exp.control.hand import HandModel
    from inhand_exp.task.goals import goal_set, to_frame

    model = HandModel.from_config(HandConfig(), ObjectConfig(), 9.81)
    good = to_frame(goal_set(model, "easy", 1, seed=5))
    files = {"empty": good.iloc[:0], "start": good.assign(x0_z=0.9), "goal": good.assign(xg_z=0.9)}
    paths = {}
    for name, frame in files.items():
        paths[name] = tmp_path / f"{name}.csv"
        frame.to_csv(paths[name], index=False)
    return paths


@pytest.fixture(scope="module")
def tiny_policy(tmp_path_factory) -> Path:
    """A policy.pt trained with the tiny budget, for the tests that only evaluate one."""
    tmp = tmp_path_factory.mktemp("tiny-policy")
    first = inhand_exp("mode=train", f"hydra.run.dir={tmp / 'train'}", cwd=tmp)
    assert first.returncode == 0, first.stderr
    return tmp / "train" / "policy.pt"


def test_eval_mode_uses_a_checkpoint_and_refuses_bad_ones(tmp_path, tiny_policy):
    policy = tiny_policy
    res = inhand_exp("mode=eval", f"checkpoint={policy}", f"hydra.run.dir={tmp_path / 'ev'}",
                     cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert len(read_log(tmp_path / "ev" / "run.mcap").topic("/eval/episode")) == 1
    (tmp_path / "text.pt").write_text("not a checkpoint\n")
    goals = bad_goal_files(tmp_path)
    ev = ["mode=eval", f"checkpoint={policy}"]
    cases = [
        (["mode=eval"], "mode=eval needs checkpoint=PATH"),
        (["mode=eval", f"checkpoint={tmp_path / 'missing.pt'}"], "not found"),
        (["mode=eval", f"checkpoint={tmp_path / 'text.pt'}"], "not a policy.pt"),
        (["mode=eval", "checkpoint=packaged:table9"], "no packaged policy 'table9'"),
        ([*ev, "object=cube"], "this configuration has"),
        ([*ev, "learner=ddpg"], "this configuration has learner=ddpg"),
        ([*ev, f"eval.goals_file={tmp_path / 'no.csv'}"], "not found"),
        ([*ev, f"eval.goals_file={goals['empty']}"], "no goal rows"),
        ([*ev, f"eval.goals_file={goals['start']}"], "line 2: the grasp cannot hold the "
                                                      "object at X0"),
        ([*ev, f"eval.goals_file={goals['goal']}"], "line 2: no grasp holds the object at Xg"),
        (["object=schema"], "object=schema is the typed schema"),
        (["sim.timestep_s=-1"], "sim.timestep_s must be > 0"),
        (["no_such_key=1"], "Could not override 'no_such_key'"),
    ]

    def refused(k: int) -> subprocess.CompletedProcess[str]:
        args = cases[k][0]
        return inhand_exp(*args, f"hydra.run.dir={tmp_path / f'bad{k}'}", cwd=tmp_path,
                          fast="learner=ddpg" not in args)  # the fast budget is PPO's

    with ThreadPoolExecutor(3) as pool:  # each refusal is a process of its own
        results = list(pool.map(refused, range(len(cases))))
    for k, ((args, message), bad) in enumerate(zip(cases, results, strict=True)):
        assert bad.returncode == 2 and message in bad.stderr, (args, bad.stderr)
        assert "Traceback" not in bad.stderr
        assert not (tmp_path / f"bad{k}").exists(), args  # a refused run writes nothing


def test_a_policy_carries_its_training_overrides_wherever_it_is_copied(tmp_path):
    from inhand_exp.analysis.frames import load
    from inhand_exp.runinfo import merged

    train = inhand_exp("mode=train", "task.reward_progress=0.1", "task.no_undo=true",
                       f"hydra.run.dir={tmp_path / 'train'}", cwd=tmp_path)
    assert train.returncode == 0, train.stderr
    trained = run_config(tmp_path / "train" / "run.mcap")
    assert trained["policy_overrides"] == merged([], trained["overrides"])  # one per key
    moved = tmp_path / "elsewhere" / "actor.pt"  # no .hydra beside it
    moved.parent.mkdir()
    moved.write_bytes((tmp_path / "train" / "policy.pt").read_bytes())
    # an evaluation of the moved file and a training that goes on from it, side by side
    with ThreadPoolExecutor(2) as pool:
        ev, more = pool.map(lambda args: inhand_exp(*args, cwd=tmp_path), [
            ["mode=eval", f"checkpoint={moved}", f"hydra.run.dir={tmp_path / 'ev'}"],
            ["mode=train", f"checkpoint={moved}", "task.reward_progress=0.2",
             f"hydra.run.dir={tmp_path / 'more'}"]])
    assert ev.returncode == 0, ev.stderr
    assert run_config(tmp_path / "ev" / "run.mcap")["policy_overrides"] == \
        trained["policy_overrides"]
    # evaluated without the filter it learned with, and told so
    assert "trained with task.no_undo=true (here: false)" in ev.stdout
    assert "reward_progress" not in ev.stdout.split("note:")[1].splitlines()[0]
    assert more.returncode == 0, more.stderr
    longer = run_config(tmp_path / "more" / "run.mcap")["policy_overrides"]
    assert "task.reward_progress=0.2" in longer and "task.reward_progress=0.1" not in longer
    runs = load([tmp_path / "train", tmp_path / "ev", tmp_path / "more"]).runs
    variants = dict(zip(runs["run_dir"].map(lambda d: Path(d).name), runs["variant"],
                        strict=True))
    # the same recipe, evaluated without its filter: a row of its own, named so
    assert variants["ev"] == variants["train"] + " | evaluated with task.no_undo=false"
    assert variants["train"] != variants["more"]
    assert "task.reward_progress=0.1" in variants["ev"]


def test_goals_mode_writes_a_test_set_that_eval_reads_back(tmp_path, tiny_policy):
    from inhand_exp.config import HandConfig, ObjectConfig
    from inhand_exp.control.hand import HandModel
    from inhand_exp.task.goals import goal_set

    res = inhand_exp("mode=goals", "goals=hard", "eval.episodes=6",
                     f"hydra.run.dir={tmp_path / 'set'}", cwd=tmp_path, fast=False)
    assert res.returncode == 0, res.stderr
    path = tmp_path / "set" / "goals.csv"
    assert "6 hard pairs written" in res.stdout and "need a flip" in res.stdout
    assert not (tmp_path / "set" / "policy.pt").exists()  # no policy involved
    model = HandModel.from_config(HandConfig(), ObjectConfig(), 9.81)
    back, made = load_goals(path), goal_set(model, "hard", 6, seed=1234, flip_share=0.25)
    assert made[3].needs_flip  # the config's flip share: every 4th hard test pair needs one
    assert [(p.contacts.posture, p.needs_flip, p.lone_down) for p in back] == [
        (p.contacts.posture, p.needs_flip, p.lone_down) for p in made]
    for a, b in zip(back, made, strict=True):
        np.testing.assert_allclose(np.r_[a.x0, a.xg, a.contacts.coords],
                                   np.r_[b.x0, b.xg, b.contacts.coords], atol=1e-8)
    ev = inhand_exp("mode=eval", f"checkpoint={tiny_policy}", f"eval.goals_file={path}",
                    f"hydra.run.dir={tmp_path / 'ev'}", "eval.episodes=6", cwd=tmp_path)
    assert ev.returncode == 0, ev.stderr
    episodes = read_log(tmp_path / "ev" / "run.mcap").topic("/eval/episode")
    assert [e["xg"] for e in episodes] == [list(p.xg) for p in back]
    assert [e["needs_flip"] for e in episodes] == [p.needs_flip for p in back]
    assert [e["lone_down"] for e in episodes] == [p.lone_down for p in back]


def test_an_evaluation_on_training_pairs_records_demonstrations_that_training_checks(
        tmp_path, tiny_policy):
    runs = {}
    for split in ("test", "train"):
        res = inhand_exp("mode=eval", f"checkpoint={tiny_policy}", f"eval.split={split}",
                         "eval.demonstrations=true",
                         f"hydra.run.dir={tmp_path / split}", cwd=tmp_path)
        assert res.returncode == 0, res.stderr
        assert "demonstrations: 1 episode, 0 successful" in res.stdout  # FAST: 1 episode
        runs[split] = read_log(tmp_path / split / "run.mcap")
    x0 = {k: [e["x0"] for e in log.topic("/eval/episode")] for k, log in runs.items()}
    assert all(a != b for a, b in zip(x0["test"], x0["train"], strict=True))  # other pairs
    demos = torch.load(tmp_path / "train" / "demonstrations.pt", weights_only=True)
    acts = runs["train"].topic("/episode/action")
    assert demos["action"].tolist() == [a["action"] for a in acts]
    assert demos["episode"].tolist() == [a["episode"] for a in acts]
    assert demos["success"].tolist() == [e["success"] for e in runs["train"].topic(
        "/eval/episode")]
    # the tiny policy solves nothing in two actions: no step to clone, refused before a run
    path = tmp_path / "train" / "demonstrations.pt"
    for extra, says in (([], "hold no step of a successful episode"),
                        (["task.posture_advice=true"], "recorded with 18 observations")):
        res = inhand_exp("mode=train", f"learner.demonstrations=[{path}]", *extra,
                         f"hydra.run.dir={tmp_path / 'clone'}", cwd=tmp_path)
        assert res.returncode == 2 and says in res.stderr, res.stderr
        assert not (tmp_path / "clone" / "run.mcap").exists()


def test_a_fixed_start_pose_starts_every_pair_and_an_unholdable_one_is_refused(tmp_path):
    cube = ["object=cube", "goals=hard", "goals.hard_goal_posture=any", "eval.episodes=4"]
    res = inhand_exp("mode=goals", *cube, "goals.x0=[0,0.25,0]",
                     f"hydra.run.dir={tmp_path / 'set'}", cwd=tmp_path, fast=False)
    assert res.returncode == 0, res.stderr
    pairs = load_goals(tmp_path / "set" / "goals.csv")
    assert [list(p.x0) for p in pairs] == [[0.0, 0.25, 0.0]] * 4
    assert len({p.contacts for p in pairs}) == 1 and len({tuple(p.xg) for p in pairs}) == 4
    bad = inhand_exp("mode=goals", *cube, "goals.x0=[0,0.6,0]",
                     f"hydra.run.dir={tmp_path / 'bad'}", cwd=tmp_path, fast=False)
    assert bad.returncode == 2 and "goals.x0=[0.0, 0.6, 0.0]: no grasp" in bad.stderr
    assert not (tmp_path / "bad").exists()


def test_a_goal_file_whose_grasps_do_not_fit_the_perturbed_object_is_refused(tmp_path,
                                                                            tiny_policy):
    res = inhand_exp("mode=goals", "goals=medium", "eval.episodes=16",
                     f"hydra.run.dir={tmp_path / 'set'}", cwd=tmp_path, fast=False)
    assert res.returncode == 0, res.stderr
    ev = inhand_exp("mode=eval", f"checkpoint={tiny_policy}",
                    f"eval.goals_file={tmp_path / 'set' / 'goals.csv'}", "perturb=longer",
                    f"hydra.run.dir={tmp_path / 'ev'}", cwd=tmp_path)
    assert ev.returncode == 2
    assert "does not fit the simulated object (perturb=longer)" in ev.stderr
    assert not (tmp_path / "ev").exists()


def test_resume_continues_an_interrupted_training_in_its_run_directory(tmp_path):
    run_dir = tmp_path / "run"
    # as if killed after 2 iterations of 8 frames: resume asks for 3
    assert FAST[0] == "train.frames=8"
    first = inhand_exp("mode=train", f"hydra.run.dir={run_dir}", *FAST[1:], "train.frames=16",
                       cwd=tmp_path, fast=False)
    assert first.returncode == 0, first.stderr
    before = (run_dir / "run.mcap").read_bytes()
    res = inhand_exp(f"resume={run_dir}", "train.frames=24", cwd=tmp_path, fast=False)
    assert res.returncode == 0, res.stderr
    assert "resuming from" in res.stdout and "iteration 2, 16 frames" in res.stdout
    assert (run_dir / "run.mcap").read_bytes() == before  # nothing already written is lost
    log = read_log(run_dir / "run-2.mcap")
    assert [(m["iteration"], m["frames"]) for m in log.topic("/train/iteration")] == [(3, 24)]
    (cfg,) = log.topic("/run/config")
    assert cfg["config"]["train"]["frames"] == 24 and cfg["config"]["mode"] == "train"
    assert cfg["config"]["learner"]["frames_per_batch"] == 8  # the run's own overrides
    done = inhand_exp(f"resume={run_dir}", "train.frames=24", cwd=tmp_path, fast=False)
    assert done.returncode == 2 and "the training is finished (24 of" in done.stderr
    assert not (run_dir / "run-3.mcap").exists()  # nothing written for it


def _default_sigint() -> None:
    """Ctrl-C's default in the child: a test run as a background job of a script inherits
    SIGINT ignored, and Python would then leave it ignored."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _stopped_by(sig: int, args: list[str], run_dir: Path, wait_for: Path, group: bool,
                cwd: Path) -> subprocess.CompletedProcess[str]:
    """Run ``inhand-exp args`` with two environment workers, send ``sig`` once ``wait_for``
    exists (to the whole process group, as Ctrl-C does, or to the main process alone)."""
    env = {**os.environ, "HYDRA_FULL_ERROR": "0"}
    proc = subprocess.Popen([*APP, *args, f"hydra.run.dir={run_dir}"], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=_default_sigint)
    try:
        deadline = time.monotonic() + 240
        while not wait_for.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.2)
        assert proc.poll() is None, proc.stderr.read()
        os.killpg(proc.pid, sig) if group else proc.send_signal(sig)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def test_an_interrupted_training_stops_cleanly_and_says_how_to_go_on(tmp_path):
    run_dir = tmp_path / "run"
    train = ["mode=train", "train.frames=100000", "learner.frames_per_batch=8",
             "learner.minibatch_size=4", "train.num_envs=2", "train.workers=2",
             "train.backend=parallel", "learner.epochs=1", "task.max_actions=2"]
    # Ctrl-C: SIGINT to every process of the group, the two workers included
    res = _stopped_by(signal.SIGINT, train, run_dir, run_dir / "policy.pt", True, tmp_path)
    assert res.returncode == 128 + signal.SIGINT, res.stderr
    assert "Traceback" not in res.stderr  # neither the main process's nor a worker's
    assert f"stopped by SIGINT; {run_dir} keeps the log" in res.stderr
    assert f"Continue with: inhand-exp resume={run_dir}" in res.stderr
    assert not (run_dir / "done.json").exists()
    first = read_log(run_dir / "run.mcap")
    assert not first.truncated  # closed on the way out, not cut
    done = [m["iteration"] for m in first.topic("/train/iteration")]
    assert done and done == list(range(1, len(done) + 1))
    kept = (run_dir / "run.mcap").read_bytes()
    # the command it names goes on from there; a SIGTERM to the main process alone (kill)
    # stops it the same way
    res = _stopped_by(signal.SIGTERM, [f"resume={run_dir}"], run_dir, run_dir / "run-2.mcap",
                      False, tmp_path)
    assert res.returncode == 128 + signal.SIGTERM, res.stderr
    assert "Traceback" not in res.stderr
    assert "stopped by SIGTERM" in res.stderr and f"resume={run_dir}" in res.stderr
    assert (run_dir / "run.mcap").read_bytes() == kept  # nothing already written is lost
    second = read_log(run_dir / "run-2.mcap")
    assert not second.truncated
    later = [m["iteration"] for m in second.topic("/train/iteration")]
    assert all(i > done[-1] for i in later)


def test_an_error_raised_while_an_interrupt_unwinds_is_the_interrupt():
    """A SIGTERM that lands inside OmegaConf building a worker's config left the config
    half-built, and OmegaConf's next error (a ConfigKeyError, raised from an AttributeError
    while the interrupt unwound) used to end the run with a traceback instead of the clean
    stop. The app looks behind such an error for the interrupt."""
    from omegaconf.errors import ConfigKeyError

    from inhand_exp.cli import Interrupted, interrupt_behind

    try:
        try:
            raise Interrupted(signal.SIGTERM)
        except KeyboardInterrupt:
            try:
                raise AttributeError("'NoneType' object has no attribute '_invalidate_flags'")
            except AttributeError as inner:
                raise ConfigKeyError("half-built") from inner
    except ConfigKeyError as err:
        stop = interrupt_behind(err)
    assert isinstance(stop, Interrupted) and stop.signum == signal.SIGTERM
    try:
        try:
            raise ValueError("a real failure")
        except ValueError as inner:
            raise RuntimeError("reported") from inner
    except RuntimeError as err:
        assert interrupt_behind(err) is None


def test_resume_refuses_what_it_cannot_resume(tmp_path):
    (tmp_path / "empty").mkdir()
    (tmp_path / "early" / ".hydra").mkdir(parents=True)
    (tmp_path / "early" / ".hydra" / "overrides.yaml").write_text("[]\n")
    for where, message in [("empty", "not a run directory"), ("early", "no policy.pt")]:
        res = inhand_exp(f"resume={tmp_path / where}", cwd=tmp_path, fast=False)
        assert res.returncode == 2 and message in res.stderr, res.stderr
        assert "Traceback" not in res.stderr
    assert sorted(p.name for p in (tmp_path / "early").iterdir()) == [".hydra"]


def test_ddpg_trains_and_evaluates_end_to_end_with_the_same_logs(tmp_path):
    """learner=ddpg: the torque env, /train/iteration with DDPG's losses, /eval/episode with
    the fields PPO's evaluation writes but the flip count (a torque policy makes no
    primitives to count), and no per-action records."""
    ppo = inhand_exp(f"hydra.run.dir={tmp_path / 'ppo'}", cwd=tmp_path)
    assert ppo.returncode == 0, ppo.stderr
    res = inhand_exp("learner=ddpg", "train.frames=16", "learner.frames_per_batch=8",
                     "learner.warmup_frames=8", "learner.batch_size=4",
                     "learner.updates_per_batch=2", "learner.train_pool=1", "train.num_envs=2",
                     "train.backend=serial", "eval.episodes=1", "task.time_limit_s=0.5",
                     f"hydra.run.dir={tmp_path / 'ddpg'}", cwd=tmp_path, fast=False)
    assert res.returncode == 0, res.stderr
    log = read_log(tmp_path / "ddpg" / "run.mcap")
    iterations = log.topic("/train/iteration")
    assert [m["frames"] for m in iterations] == [8, 16]
    assert set(iterations[-1]["losses"]) == {"loss_actor", "loss_value"}
    (episode,) = log.topic("/eval/episode")
    (reference,) = read_log(tmp_path / "ppo" / "run.mcap").topic("/eval/episode")
    assert "n_flips" in reference and "n_flips" not in episode
    assert set(episode) == set(reference) - {"n_flips"} and episode["learner"] == "ddpg"
    assert episode["sim_time_s"] <= 0.5 + 1e-6
    assert log.topic("/episode/action") == []
    assert (tmp_path / "ddpg" / "policy.pt").is_file()


def test_a_study_trains_each_policy_once_and_skips_finished_jobs_when_run_again(tmp_path):
    """Two evaluation jobs of one policy (train.store): one trains it, the other reuses it. The
    study run again skips both; a job without its done marker runs again, keeping its old log."""
    store, sweep = tmp_path / "store", tmp_path / "study"
    args = ["-m", "goals=easy,medium", "goals.train_groups=[easy,medium]",
            f"train.store={store}", f"hydra.sweep.dir={sweep}"]
    first = inhand_exp(*args, cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    assert first.stdout.count("reusing the policy in") == 1
    (policy,) = store.glob("ppo-pole-noise_none-seed0-*/policy.pt")
    trained = [len(read_log(sweep / j / "run.mcap").topic("/train/iteration")) for j in "01"]
    assert sorted(trained) == [0, 1]  # one job trained, the other only evaluated
    for j in "01":
        assert len(read_log(sweep / j / "run.mcap").topic("/eval/episode")) == 1
        assert (sweep / j / "done.json").is_file()
    stamp = policy.stat().st_mtime_ns
    again = inhand_exp(*args, cwd=tmp_path)
    assert again.returncode == 0 and again.stdout.count("skipped") == 2, again.stdout
    (sweep / "1" / "done.json").unlink()  # as if job 1 had been killed
    before = (sweep / "1" / "run.mcap").read_bytes()
    third = inhand_exp(*args, cwd=tmp_path)
    assert third.returncode == 0, third.stderr
    assert (sweep / "1" / "run-interrupted.mcap").read_bytes() == before  # kept as it was
    assert (sweep / "1" / "done.json").is_file() and "reusing the policy" in third.stdout
    assert policy.stat().st_mtime_ns == stamp  # never trained again


def test_the_sweep_files_compose(tmp_path):
    for study, extra in (("comparison", ["+recipe=ddpg", "goals=hard"]),
                         ("robustness", ["+recipe=ppo", "perturb=thicker", "noise=paper"]),
                         ("cube", ["+recipe=ppo"])):
        res = subprocess.run([*APP, "--config-dir", str(SWEEPS), "--config-name", study,
                              *extra, "+profile=quick", "--cfg", "job"], cwd=tmp_path,
                             capture_output=True, text=True, timeout=120)
        assert res.returncode == 0, (study, res.stderr)
        assert "store: logs/studies/" in res.stdout and "episodes: 20" in res.stdout
        # the quick profile writes apart from the full study (the job's name is the study's)
        res = subprocess.run([*APP, "--config-dir", str(SWEEPS), "--config-name", study,
                              *extra, "+profile=quick", "--cfg", "all", "--resolve"],
                             cwd=tmp_path, capture_output=True, text=True, timeout=120)
        assert res.returncode == 0, (study, res.stderr)
        assert f"dir: logs/studies/quick/{study}" in res.stdout


@pytest.mark.parametrize("launcher", [[], JOBLIB], ids=["basic", "joblib"])
def test_a_failing_job_does_not_stop_the_sweep(tmp_path, launcher):
    """Two of four jobs get a bad goal file: the other two finish with intact logs, the
    failures are named at the end with their error (exit 1), and the analysis reads the rest."""
    from inhand_exp.analysis.frames import load

    bad = tmp_path / "bad.csv"
    bad.write_text("group,x0_x\n")
    sweep = tmp_path / "sweep"
    res = inhand_exp("-m", "seed=0,1", f"eval.goals_file=null,{bad}",
                     f"hydra.sweep.dir={sweep}", *launcher, cwd=tmp_path)
    assert res.returncode == 1, res.stderr
    tail = res.stderr[res.stderr.index("2 job(s) of the sweep"):]
    assert "  1: " in tail and "  3: " in tail and "missing column(s)" in tail
    for job in ("0", "2"):
        log = read_log(sweep / job / "run.mcap")
        assert not log.truncated and len(log.topic("/eval/episode")) == 1
    for job in ("1", "3"):
        assert "missing column(s)" in (sweep / job / "failed.txt").read_text()
        assert not (sweep / job / "run.mcap").exists()
    frames = load([sweep], warn=lambda m: None)
    assert len(frames.runs) == 2 and len(frames.episodes) == 2


def test_resuming_from_one_checkpoint_twice_gives_identical_training(tmp_path):
    """Resume is deterministic: two copies of an interrupted run, resumed alike, log the same
    iterations and save the same networks. A resumed run does not equal one that never
    stopped: the episodes under way at the cut are not saved, so the resumed environments start
    fresh episodes, seeded from the seed and the iteration (the networks, optimiser, counters
    and torch's RNG are restored exactly). The difference is bounded to what follows the cut:
    up to it, the interrupted run and the uninterrupted one are identical."""
    import shutil

    import torch

    base = tmp_path / "base"
    first = inhand_exp("mode=train", "train.frames=16", f"hydra.run.dir={base}", *FAST[1:],
                       cwd=tmp_path, fast=False)
    assert first.returncode == 0, first.stderr
    for name in ("a", "b"):
        shutil.copytree(base, tmp_path / name)
    # both copies resumed, and a run that never stopped, side by side (processes of their own)
    straight = tmp_path / "straight"
    runs = [[f"resume={tmp_path / 'a'}", "train.frames=32"],
            [f"resume={tmp_path / 'b'}", "train.frames=32"],
            ["mode=train", "train.frames=32", f"hydra.run.dir={straight}", *FAST[1:]]]
    with ThreadPoolExecutor(3) as pool:
        for res in pool.map(lambda args: inhand_exp(*args, cwd=tmp_path, fast=False), runs):
            assert res.returncode == 0, res.stderr
    states, logs = [], []
    for name in ("a", "b"):
        log = read_log(tmp_path / name / "run-2.mcap").topic("/train/iteration")
        logs.append([(m["iteration"], m["frames"], m["losses"], m["mean_return"]) for m in log])
        states.append(torch.load(tmp_path / name / "policy.pt", weights_only=True))
    assert logs[0] == logs[1] and [m[0] for m in logs[0]] == [3, 4]
    for key in ("actor", "critic"):
        for k, v in states[0][key].items():
            assert torch.equal(v, states[1][key][k]), (key, k)
    # the bound on the difference from a run that never stopped: everything before the cut
    # is identical; only the iterations after it differ
    def iterations(path):
        return [(m["iteration"], m["frames"], m["losses"], m["mean_return"])
                for m in read_log(path).topic("/train/iteration")]

    assert iterations(straight / "run.mcap")[:2] == iterations(base / "run.mcap")


def test_the_default_run_shows_the_packaged_policy_on_every_group(tmp_path):
    """`inhand-exp` alone: the packaged Table II policy on a sample of each group, said so on
    screen, beside the paper, with one hard episode replayed."""
    run = tmp_path / "demo"
    res = subprocess.run([*APP, "eval.episodes=2", "train.num_envs=2", "train.backend=serial",
                          "log.progress=false", f"hydra.run.dir={run}"], cwd=tmp_path,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "the packaged Table II policy" in res.stdout and "first 2 test pairs" in res.stdout
    for group in ("easy", "medium", "hard"):
        assert f"ppo {group} pole" in res.stdout
    episodes = read_log(run / "run.mcap").topic("/eval/episode")
    assert sorted(e["group"] for e in episodes) == ["easy"] * 2 + ["hard"] * 2 + ["medium"] * 2
    assert list(run.glob("episode-*.gif")) and "replayed in" in res.stdout
    assert not (run / "policy.pt").exists()  # nothing trained
    for banner in ("pybullet build time", "Running HiGHS"):  # C libraries' banners: silenced
        assert banner not in res.stdout + res.stderr


def test_a_packaged_policy_is_named_by_checkpoint_and_its_task_settings_are_asked_for(tmp_path):
    """`checkpoint=packaged:NAME` shows another packaged policy the way `inhand-exp` alone shows
    the Table II one, and says which of its training's task settings the run lacks."""
    common = ["checkpoint=packaged:table2_clone_seed0", "eval.episodes=1", "train.num_envs=1",
              "train.backend=serial", "log.progress=false", "log.sim_state_hz=0"]
    bare = subprocess.run([*APP, *common, f"hydra.run.dir={tmp_path / 'bare'}"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    assert bare.returncode == 0, bare.stderr
    assert "the packaged policy table2_clone_seed0 (1,024 frames" in bare.stdout
    assert "trained with task.no_undo=true (here: false)" in bare.stdout
    same = subprocess.run([*APP, *common, "task.no_undo=true",
                           f"hydra.run.dir={tmp_path / 'same'}"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert same.returncode == 0, same.stderr
    assert "note: the policy was trained with" not in same.stdout
    assert len(read_log(tmp_path / "same" / "run.mcap").topic("/eval/episode")) == 3


def test_help_names_the_app_and_lists_only_real_options(tmp_path):
    res = subprocess.run([*APP, "--help"], cwd=tmp_path, capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0 and res.stdout.startswith("inhand-exp:")
    groups = res.stdout.split("== Configuration groups ==")[1].split("== Config ==")[0]
    assert "schema" not in groups and "learner: ppo, ddpg, search" in groups
