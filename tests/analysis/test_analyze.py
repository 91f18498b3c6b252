"""inhand-analyze: logs below a path become frames, the paper's tables (mean and std over seeds)
and plots; foreign, corrupt and truncated files are handled."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from inhand_exp.analysis import tables
from inhand_exp.analysis.cli import main
from inhand_exp.analysis.frames import load, variant
from inhand_exp.record import RunLog
from inhand_exp.runinfo import run_config_message


def episode(k: int, group: str, success: bool, seed: int, dropped: bool = False) -> dict:
    return {"episode": k, "group": group, "success": success, "dropped": dropped,
            "timeout": not (success or dropped), "sim_time_s": 2.0 + k, "n_actions": 3,
            "n_invalid": 0, "x0": [0.0, 0.3, 0.0], "xg": [0.01, 0.3, 0.1],
            "final_pose": [0.0, 0.3, 0.0], "final_err_m": 0.0, "final_err_rad": 0.0,
            "needs_flip": group == "hard" and k % 2 == 0,
            "lone_down": group == "medium" and k % 3 == 0,
            "n_flips": int(group == "hard" and k % 4 == 0), "object": "pole", "perturb": "none",
            "noise": "none", "learner": "ppo", "seed": seed}


def write_run(compose_cfg, run_dir: Path, seed: int, wins: dict[str, int], n: int = 10,
              overrides: tuple[str, ...] = (), policy: tuple[str, ...] | None = None) -> Path:
    run_dir.mkdir(parents=True)
    cfg = compose_cfg(f"seed={seed}", *overrides)
    path = run_dir / "run.mcap"
    with RunLog(path) as log:
        log.write("/run/config", run_config_message(
            cfg, run_dir, [f"seed={seed}", *overrides],
            policy_overrides=None if policy is None else list(policy)))
        for it in range(1, 4):
            log.write("/train/iteration", {
                "iteration": it, "frames": 1024 * it, "wall_s": 10.0 * it,
                "losses": {"loss_objective": 0.1}, "mean_return": 0.0,
                "success_rate": 0.2 * it + 0.1 * seed, "drop_rate": 0.0,
                "actions_per_s": 50.0, "collect_s": 9.0, "learn_s": 1.0})
        for group, w in wins.items():
            for k in range(n):
                log.write("/eval/episode", episode(k, group, k < w, seed, dropped=k == n - 1))
    return path


@pytest.fixture
def sweep(tmp_path, compose_cfg) -> Path:
    root = tmp_path / "sweep"
    write_run(compose_cfg, root / "0", 0, {"easy": 8, "medium": 5, "hard": 4})
    write_run(compose_cfg, root / "1", 1, {"easy": 6, "medium": 5, "hard": 2})
    write_run(compose_cfg, root / "2", 0, {"easy": 3}, overrides=("task.reward_progress=0.1",))
    (root / "junk.mcap").write_text("not an mcap file\n")
    with RunLog(root / "empty.mcap"):
        pass  # a valid MCAP with no /run/config
    good = (root / "1" / "run.mcap").read_bytes()
    (root / "killed").mkdir()
    (root / "killed" / "run.mcap").write_bytes(good[:len(good) * 2 // 3])  # writer killed
    return root


def test_frames_tables_and_skipped_files(sweep):
    warnings: list[str] = []
    frames = load([sweep], warn=warnings.append)
    assert sorted(Path(p).name for p, _ in frames.skipped) == ["empty.mcap", "junk.mcap"]
    assert any("junk.mcap" in w for w in warnings) and any("truncated" in w for w in warnings)
    assert len(frames.runs) == 4 and frames.runs["truncated"].sum() == 1
    assert set(frames.runs["variant"]) == {"default", "task.reward_progress=0.1"}
    rows = tables.build(frames.episodes[~frames.episodes["log"].str.contains("killed")],
                        "comparison")
    easy = rows[(rows["group"] == "easy") & (rows["variant"] == "default")].iloc[0]
    assert easy["seeds"] == 2 and easy["episodes"] == 20
    assert easy["success_rate_mean"] == pytest.approx(0.7)
    assert easy["success_rate_std"] == pytest.approx(pd.Series([0.8, 0.6]).std())
    assert easy["drop_rate_mean"] == pytest.approx(0.1)
    assert easy["paper_success"] == pytest.approx(0.954)
    flips = rows[rows["group"] == tables.NEEDS_FLIP].iloc[0]
    assert flips["episodes"] == 10  # the even hard episodes of both seeds
    assert flips["success_rate_mean"] == pytest.approx((2 / 5 + 1 / 5) / 2)  # 0, 2 and 0 won
    rest = rows[rows["group"] == tables.NO_FLIP].iloc[0]
    assert rest["episodes"] == 10  # the odd ones
    assert rest["success_rate_mean"] == pytest.approx((2 / 5 + 1 / 5) / 2)  # 1, 3 and 1 won
    assert (flips["drop_rate_mean"], rest["drop_rate_mean"]) == (0.0, pytest.approx(0.2))
    assert (flips["flipped_rate_mean"], rest["flipped_rate_mean"]) == (pytest.approx(0.6), 0.0)
    assert "| flipped |" in tables.render(rows, "comparison")
    older = frames.episodes.drop(columns="n_flips")  # logs written before the count
    assert "flipped" not in tables.render(tables.build(older, "comparison"), "comparison")
    assert rows["group"].tolist().index(tables.NO_FLIP) == \
        rows["group"].tolist().index(tables.NEEDS_FLIP) + 1
    lone = rows[rows["group"] == tables.LONE_DOWN].iloc[0]
    assert lone["episodes"] == 8  # medium episodes 0, 3, 6, 9 of both seeds; 0 and 3 succeed
    assert lone["success_rate_mean"] == pytest.approx(0.5)
    assert rows["group"].tolist().index(tables.LONE_DOWN) == \
        rows["group"].tolist().index("medium") + 1
    shaped = rows[rows["variant"] == "task.reward_progress=0.1"]
    assert shaped["success_rate_mean"].tolist() == [pytest.approx(0.3)]


def test_an_evaluation_with_another_filter_is_a_row_of_its_own(tmp_path, compose_cfg):
    """One policy, trained with `task.no_undo=true`, evaluated with it and without: two
    variants, two rows, not one row of both runs' episodes."""
    trained = ("mode=train", "task.reward_progress=0.1", "task.no_undo=true")
    root = tmp_path / "evals"
    write_run(compose_cfg, root / "as_trained", 0, {"medium": 6},
              overrides=("mode=eval", "task.no_undo=true"), policy=trained)
    write_run(compose_cfg, root / "plain", 0, {"medium": 4}, overrides=("mode=eval",),
              policy=trained)
    frames = load([root], warn=lambda _: None)
    variants = dict(zip(frames.runs["run_dir"].map(lambda p: Path(p).name),
                        frames.runs["variant"], strict=True))
    assert variants == {
        "as_trained": "task.no_undo=true task.reward_progress=0.1",
        "plain": "task.no_undo=true task.reward_progress=0.1 | evaluated with task.no_undo=false"}
    rows = tables.build(frames.episodes, "comparison")
    medium = rows[rows["group"] == "medium"].set_index("variant")
    assert medium.loc[variants["as_trained"], "success_rate_mean"] == pytest.approx(0.6)
    assert medium.loc[variants["plain"], "success_rate_mean"] == pytest.approx(0.4)


def test_reading_in_several_processes_gives_the_same_frames(sweep, monkeypatch):
    import inhand_exp.analysis.frames as frames_module

    monkeypatch.setattr(frames_module, "PARALLEL_BYTES", 0)  # the pool even for small logs
    said: dict[int, list[str]] = {1: [], 2: []}
    one, two = (load([sweep], warn=said[n].append, jobs=n) for n in (1, 2))
    for name in ("runs", "iterations", "episodes"):
        pd.testing.assert_frame_equal(getattr(one, name), getattr(two, name))
    assert one.skipped == two.skipped and len(one.skipped) == 2
    assert said[1] == said[2] and said[1]


def test_cli_refuses_a_jobs_count_below_one(sweep, capsys):
    with pytest.raises(SystemExit) as exit_:
        main([str(sweep), "--jobs", "0"])
    assert exit_.value.code == 2
    assert "--jobs must be a whole number >= 1, not '0'" in capsys.readouterr().err


def test_cli_prints_the_table_and_writes_frames_and_plots(sweep, tmp_path, capsys):
    out = tmp_path / "out"
    main([str(sweep / "0"), str(sweep / "1"), "--out", str(out), "--table", "comparison"])
    text = capsys.readouterr().out
    assert "| ppo | easy | 2 | 20 | 70.0 ± 14.1 % | 95.4 % |" in text
    for name in ("runs", "iterations", "episodes"):
        parquet, csv = pd.read_parquet(out / f"{name}.parquet"), pd.read_csv(out / f"{name}.csv")
        assert len(parquet) == len(csv) > 0
    assert (out / "table_comparison.csv").is_file()
    assert (out / "learning_curves.png").stat().st_size > 1000
    assert (out / "by_group.png").stat().st_size > 1000
    main([str(sweep / "0"), "--out", str(out), "--table", "comparison", "--format", "csv"])
    assert capsys.readouterr().out.count("ppo,default,easy") == 1


def test_perturbation_bars_split_by_noise(tmp_path):
    from inhand_exp.analysis.plots import outcome_bars, outcome_stats
    rows = []
    for noise, wins in (("none", {"none": 9, "heavier": 7}), ("paper", {"none": 6, "heavier": 5})):
        for perturb, w in wins.items():
            for k in range(10):
                e = episode(k, "medium", k < w, seed=0, dropped=k == 9 and w < 9)
                rows.append(e | {"noise": noise, "perturb": perturb})
    frame = pd.DataFrame(rows)
    stats = outcome_stats(frame, "perturb", hue=("learner", "noise")).set_index(
        ["noise", "perturb"])
    assert len(stats) == 4  # two noise settings x two objects, not merged into two bars
    assert stats.loc[("none", "heavier"), "success"] == pytest.approx(0.7)
    assert stats.loc[("paper", "none"), "drop"] == pytest.approx(0.1)
    assert outcome_bars(frame, "perturb", tmp_path / "p.png", hue=("learner", "noise")) \
        .stat().st_size > 1000


def test_robustness_rows_give_the_change_from_the_trained_object():
    rows = []
    wins = {("none", "none"): 9, ("none", "heavier"): 7, ("paper", "none"): 6,
            ("paper", "thinner"): 5, ("paper", "longer"): 6}
    for (noise, perturb), w in wins.items():
        rows += [episode(k, "medium", k < w, seed=0) | {"noise": noise, "perturb": perturb,
                                                        "variant": "default"}
                 for k in range(10)]
    out = tables.build(pd.DataFrame(rows), "robustness").set_index(["noise", "perturb"])
    assert out.loc[("none", "heavier"), "vs_trained"] == pytest.approx(-0.2)
    assert out.loc[("paper", "longer"), "vs_trained"] == pytest.approx(0.0)
    assert out.loc[("none", "none"), "vs_trained"] == pytest.approx(0.0)
    # the paper's own change (Table III: 91.0 % thinner against 93.2 % with noise)
    assert out.loc[("paper", "thinner"), "paper_vs_trained"] == pytest.approx(0.910 - 0.932)
    # paired over the ten pairs: the trained object alone solved two (k = 7, 8), the
    # heavier pole none alone: sqrt(2 - 2^2 / 10) / 10
    assert out.loc[("none", "heavier"), "vs_trained_se"] == pytest.approx(np.sqrt(1.6) / 10)
    assert out.loc[("none", "none"), "vs_trained_se"] == 0.0
    assert out.loc[("none", "heavier"), "vs_trained_pairs"] == 10
    text = tables.render(out.reset_index(), "robustness")
    assert "vs trained object" in text and "| -20.0 ± 12.6 pts | 10 |" in text
    alone = tables.build(pd.DataFrame(rows[10:20]), "robustness")  # no trained-object row
    assert alone["vs_trained"].isna().all() and "| - |" in tables.render(alone, "robustness")


def test_a_cell_missing_a_seed_is_compared_with_the_same_seeds_of_the_trained_object():
    """Midway through a sweep the trained object has seeds 0 and 1 and the thinner pole only
    seed 0: its change is seed 0's, not seed 0's success minus the two seeds' mean."""
    rows = [episode(k, "medium", k < wins, seed=seed) | {"variant": "default"}
            for seed, wins in ((0, 8), (1, 4)) for k in range(10)]
    thin = [episode(k, "medium", k < 7, seed=0) | {"perturb": "thinner", "variant": "default"}
            for k in range(10)]
    out = tables.build(pd.DataFrame(rows + thin), "robustness").set_index("perturb")
    assert out.loc["none", "success_rate_mean"] == pytest.approx(0.6)
    assert out.loc["thinner", "vs_trained"] == pytest.approx(-0.1)  # 0.7 - 0.8, not 0.7 - 0.6
    assert out.loc["none", "vs_trained"] == 0.0


def test_the_change_leaves_out_pairs_drawn_again_for_the_perturbation():
    """A pair the perturbed pole was given again (another X0) is not compared with the
    trained object's; the rest are, episode by episode. Here the thinner pole solves its
    drawn-again pair and the trained object failed its own: counted, they would make the
    change -0.4 instead of -5/9."""
    rows = [episode(k, "medium", k < 8, seed=0) | {"variant": "default"} for k in range(10)]
    thin = [episode(k, "medium", k in (0, 1, 8, 9), seed=0)
            | {"perturb": "thinner", "variant": "default"} for k in range(10)]
    thin[9]["x0"] = [0.01, 0.3, 0.0]  # drawn again: it does not count
    stats = tables.paired(pd.DataFrame(rows + thin)).loc[("ppo", "default", "none", "thinner")]
    # nine pairs: the trained object alone solved k = 2..7 (6), the thinner pole alone k = 8
    assert stats["pairs"] == 9 and stats["change"] == pytest.approx((1 - 6) / 9)
    assert stats["se"] == pytest.approx(np.sqrt(7 - 5 ** 2 / 9) / 9)
    out = tables.build(pd.DataFrame(rows + thin), "robustness").set_index("perturb")
    assert out.loc["thinner", "vs_trained"] == pytest.approx(-5 / 9)
    assert out.loc["thinner", "success_rate_mean"] == pytest.approx(0.4)  # all ten, still


def test_cli_refuses_paths_without_logs(tmp_path, capsys):
    with pytest.raises(SystemExit) as end:
        main([str(tmp_path / "nowhere")])
    assert end.value.code == 2 and "nowhere" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    with pytest.raises(SystemExit) as end:
        main([str(tmp_path / "empty")])
    assert end.value.code == 2


def test_variant_keeps_only_what_changes_the_policy():
    assert variant(["seed=3", "mode=eval", "goals=hard", "eval.episodes=500",
                    "hydra.run.dir=x", "checkpoint=a/policy.pt",
                    "learner.cache_dir=logs/cache"]) == "default"
    assert variant(["task.reward_progress=0.1", "seed=1",
                    "goals.train_groups=[easy,hard]"]) == (
        "goals.train_groups=[easy,hard] task.reward_progress=0.1")


def test_a_training_on_its_own_group_has_that_group_in_its_variant():
    """Without ``goals.train_groups`` a training draws from its ``goals`` group: policies
    trained on medium and on hard goals are two recipes; an evaluation's group is not one."""
    medium = variant(["mode=train", "goals=medium", "task.reward_progress=0.1"])
    assert medium == "goals.train_groups=[medium] task.reward_progress=0.1"
    assert variant(["mode=train_eval", "goals=hard"]) == "goals.train_groups=[hard]"
    assert variant(["mode=train", "goals=hard", "goals.train_groups=[easy,hard]"]) == (
        "goals.train_groups=[easy,hard]")
    assert variant(["mode=eval", "goals=hard", "task.reward_progress=0.1"]) == (
        "task.reward_progress=0.1")


def test_a_recipe_choice_and_its_values_given_one_by_one_are_one_variant():
    recipe = variant(["+recipe=ppo", "+profile=full", "seed=2", "goals=hard"])
    assert recipe == variant(["mode=train", "train.frames=163840", "task.reward_progress=0.1",
                              "goals.train_groups=[easy,medium,hard]"])
    assert "task.reward_progress=0.1" in recipe
    changed = variant(["+recipe=ppo", "task.reward_progress=0.2"])  # a later value wins
    assert "task.reward_progress=0.2" in changed and "0.1" not in changed
    assert variant(["+recipe=nosuch"]) == "+recipe=nosuch"  # no file: kept as written


def test_an_older_eval_log_takes_its_variant_from_the_checkpoints_record(tmp_path, compose_cfg):
    """A log written before ``/run/config`` had ``policy_overrides``, of an evaluation of a
    packaged actor (no ``.hydra`` beside it), has the variant of the actor's training."""
    import torch

    from inhand_exp.experiment import PACKAGED, packaged_policy
    from inhand_exp.learn.checkpoint import trained_with

    path = tmp_path / "ev" / "run.mcap"
    path.parent.mkdir()
    own = ["mode=eval", f"checkpoint={packaged_policy()}", "+profile=full"]
    with RunLog(path) as log:
        log.write("/run/config", run_config_message(compose_cfg(*own), path.parent, own))
    recorded = trained_with(torch.load(packaged_policy(), weights_only=True))
    assert recorded, f"{PACKAGED} records no training overrides"
    assert load([path]).runs["variant"].tolist() == [variant(recorded)] != [variant(own)]


def test_rows_follow_the_papers_order():
    import pandas as pd

    from inhand_exp.analysis.tables import in_paper_order

    frame = pd.DataFrame({"learner": ["ppo"] * 6,
                          "perturb": ["thinner", "none", "shorter", "heavier", "none", "odd"],
                          "noise": ["none", "paper", "none", "none", "none", "none"]})
    out = in_paper_order(frame, ["learner", "perturb", "noise"])
    assert list(zip(out.perturb, out.noise, strict=True)) == [
        ("none", "none"), ("none", "paper"), ("heavier", "none"), ("thinner", "none"),
        ("shorter", "none"), ("odd", "none")]  # unknown names last


def test_a_job_run_again_after_an_interruption_counts_its_episodes_once(tmp_path, compose_cfg):
    import os

    job = tmp_path / "job"
    write_run(compose_cfg, job, 0, {"medium": 1}, n=3)  # the attempt that was cut
    first = job / "run.mcap"
    first.rename(job / "run-interrupted.mcap")
    os.utime(job / "run-interrupted.mcap", (1, 1))  # older
    write_run(compose_cfg, tmp_path / "again", 0, {"medium": 5}, n=6)
    (tmp_path / "again" / "run.mcap").rename(job / "run.mcap")
    warnings = []
    frames = load([tmp_path], warn=warnings.append)
    eps = frames.episodes
    assert len(eps) == 6 and eps["success"].sum() == 5  # the rerun's six, not 3 + 6
    assert (eps["log"] == str(job / "run.mcap")).all()
    assert len(frames.iterations) == 3  # iterations 1-3 once
    assert any("3 rows of an earlier, interrupted attempt" in w for w in warnings)
