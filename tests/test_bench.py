"""``inhand-bench`` smoke runs: the last line is JSON with the documented keys; bad input fails."""

from __future__ import annotations

import json

import numpy as np
import pytest

from inhand_exp.bench import trials
from inhand_exp.bench.cli import load_config, main
from inhand_exp.config import PerturbConfig

RESULT_KEYS = {"trials", "success_rate", "drop_rate", "mean_err_m", "max_err_m", "mean_err_rad",
               "max_err_rad", "sim_s", "wall_s"}


def last_json(capsys) -> dict:
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def test_primitives_prints_json_with_the_documented_keys(capsys):
    main(["primitives", "--only", "repose,slide", "--trials", "2", "--seed", "3"])
    out = last_json(capsys)
    assert out["object"] == "pole"
    assert set(out["results"]) == {"repose", "slide"}
    for res in out["results"].values():
        assert set(res) >= RESULT_KEYS and res["trials"] == 2
        assert 0.0 <= res["success_rate"] <= 1.0 and 0.0 <= res["drop_rate"] <= 1.0


def test_the_perturbed_section_runs_every_pole_primitive_on_every_perturbation(capsys):
    """Slides and flips too, with the controllers' nominal model: on the thinner pole both once
    never ended done (judged on the nominal face, 5 mm off the real one)."""
    main(["primitives", "--only", "perturbed", "--trials", "2"])
    out = last_json(capsys)["perturbed"]
    assert set(out) == {"heavier", "lighter", "thicker", "thinner", "longer", "shorter",
                        "noise=paper"}
    for setting in out.values():
        assert set(setting) == {"repose", "slide", "flip_left", "flip_right"}
    thinner = out["thinner"]
    assert all(thinner[p]["success_rate"] > 0 for p in ("slide", "flip_left", "flip_right"))


def test_the_perturbed_section_runs_the_settings_and_primitives_asked_for(capsys):
    main(["primitives", "--only", "perturbed,flip_right", "--perturbations",
          "thinner,noise=paper", "--trials", "1"])
    out = last_json(capsys)
    assert set(out["results"]) == {"flip_right"}  # the nominal section named, too
    assert {k: set(v) for k, v in out["perturbed"].items()} == {
        "thinner": {"flip_right"}, "noise=paper": {"flip_right"}}
    with pytest.raises(SystemExit):
        main(["primitives", "--only", "perturbed", "--perturbations", "thiner"])
    assert "unknown thiner" in capsys.readouterr().err


def test_reposes_stay_allowed_on_a_thinner_pole():
    """The nominal model checks each finger's links against the face where its tip touches:
    checked against the nominal face, 5 mm outside a thinner pole's, the distal links seemed to
    cut into it and half the grasps allowed no repose at all (95 of 200 at seed 0)."""
    bench = trials.Bench(load_config("pole", []), PerturbConfig(name="thinner", width_scale=0.5))
    runs = [trials.repose(bench, np.random.default_rng([5, i])) for i in range(40)]
    started = [r for r in runs if r is not None]
    assert len(started) >= 36, len(started)
    assert sum(r.success for r in started) >= len(started) - 1


def test_results_do_not_depend_on_the_number_of_workers(capsys):
    main(["primitives", "--only", "repose", "--trials", "3"])
    one = last_json(capsys)["results"]["repose"]
    main(["primitives", "--only", "repose", "--trials", "3", "--workers", "2"])
    two = last_json(capsys)["results"]["repose"]
    assert one["mean_err_m"] == two["mean_err_m"] and one["sim_s"] == two["sim_s"]


def test_cube_sections(capsys):
    main(["primitives", "--object", "cube", "--only", "hold,release", "--trials", "1"])
    assert set(last_json(capsys)["results"]) == {"hold", "release"}


def test_speed_reports_rates_and_their_ratio(capsys):
    main(["speed", "--seconds", "0.3", "--primitive-runs", "1"])
    out = last_json(capsys)
    assert out["raw_steps_per_s"] > out["loop_steps_per_s"] > 0
    assert out["ratio"] == pytest.approx(out["loop_steps_per_s"] / out["raw_steps_per_s"])
    assert {"repose", "slide"} <= set(out["ms_per_primitive"])


def test_env_reports_its_efficiency_from_the_steps_it_counted(capsys):
    """The physics steps the worlds counted equal the simulated time over the timestep, and the
    efficiency is their rate over the raw stepSimulation rate of as many processes."""
    main(["env", "--steps", "3", "train.num_envs=2", "task.max_actions=2"])
    out = last_json(capsys)
    assert out["actions"] == 6 and out["workers"] == 1
    assert out["sim_steps"] == round(out["sim_s_per_action"] * out["actions"]
                                     / out["physics_dt_s"])
    assert out["sim_steps_per_action"] * out["actions"] == pytest.approx(out["sim_steps"])
    assert out["sim_steps_per_s"] == pytest.approx(out["sim_steps"] / out["wall_s"])
    assert out["raw_steps_per_s"] == pytest.approx(out["raw_steps_per_core"] * out["workers"])
    assert 0.0 < out["efficiency"] <= 1.0
    assert out["efficiency"] == pytest.approx(out["sim_steps_per_s"] / out["raw_steps_per_s"])
    ms = out["ms_per_action"]
    assert ms["filter"] > 0.0 and ms["execute"] > ms["step_simulation"] > 0.0
    worker_ms = 1e3 * out["wall_s"] * out["workers"] / out["actions"]
    assert ms["filter"] + ms["execute"] < worker_ms
    assert out["physics_share"] == pytest.approx(ms["step_simulation"] / worker_ms)
    assert 0.0 < out["physics_share"] < 1.0


def test_flips_counts_every_flip_it_checks_once(capsys):
    main(["flips", "--trials", "6", "--seed", "2"])
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["grasps"] == 6 and 0 < out["checked"] <= 12  # at most two flips per grasp
    assert sum(out["reasons"].values()) == out["checked"] == sum(out["theta_checked"])
    assert out["accepted"] == out["reasons"].get("accepted", 0) == sum(out["theta_accepted"])
    assert all(a <= c for a, c in zip(out["theta_accepted"], out["theta_checked"], strict=True))


def test_graph_reports_its_size_and_cost(capsys):
    main(["graph", "task.workspace_x_m=[-0.02,0.02]", "task.workspace_z_m=[0.32,0.36]",
          "task.workspace_theta_rad=[-0.2,0.2]", "--seed", "1"])
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["nodes"] > 0 and out["edges"] > out["nodes"]
    assert out["cells"] >= out["nodes"] and out["build_s"] > 0 and out["query_s"] > 0


def test_random_torques_drop_the_pole_and_the_controllers_stay_far_below_the_limit(capsys):
    """The end-to-end policy's starting point: under random torques of any scale the pole is
    lost within the first fraction of a second, while the controllers hold it with torques
    mostly well inside ``hand.max_torque_nm``."""
    main(["torques", "--trials", "2", "--actions", "6", "--seed", "1"])
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["episodes"] == 2 and set(out["held_max_s"]) == {"0.0", "0.1", "0.3", "1.0", "10.0"}
    assert all(0.0 < t < 1.0 for t in out["held_max_s"].values())
    pct = list(out["controller_abs_torque_pct"].values())
    assert out["controller_steps"] > 6 and pct == sorted(pct)
    assert 0.0 < pct[2] < out["max_torque_nm"] / 2 and pct[-1] <= out["max_torque_nm"]
    assert 0.0 <= out["controller_at_limit"] < 0.01


def test_goals_times_a_draw_of_every_training_group(capsys):
    """Each group's pairs are drawn with the run's goals config; the flip group's pairs all
    need a flip, the lone group's all need the lone finger lower, and the easy ones neither."""
    main(["goals", "--pairs", "2", "--seed", "3"])
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert set(out["ms_per_pair"]) == {"easy", "medium", "hard", "flip", "lone"}
    assert all(v > 0.0 for v in out["ms_per_pair"].values()) and out["raw_steps_per_s"] > 0
    assert out["needs_flip"]["flip"] == 2 and out["needs_flip"]["easy"] == 0
    assert out["lone_down"]["lone"] == 2 and out["lone_down"]["easy"] == 0
    with pytest.raises(SystemExit, match="2"):
        main(["goals", "--pairs", "0"])


def test_bad_input_is_refused():
    with pytest.raises(SystemExit, match="2"):
        main(["primitives", "--trials", "0"])
    with pytest.raises(SystemExit, match="object.mass_kg must be > 0"):
        main(["primitives", "object.mass_kg=-1"])
    with pytest.raises(SystemExit, match="Could not override 'sim.timestep'"):
        main(["primitives", "sim.timestep=0.01"])


def test_primitive_gains_come_from_the_config():
    from inhand_exp.bench.cli import load_config
    from inhand_exp.bench.trials import Bench

    bench = Bench(load_config("pole", ["primitives.kp=100", "primitives.min_normal_force_n=0.2",
                                       "primitives.friction_margin=0.7"]))
    assert (bench.prim.kp, bench.prim.min_normal_force_n, bench.prim.friction_margin) == (
        100, 0.2, 0.7)


def test_the_flip_count_uses_the_configured_primitives():
    """``inhand-bench flips`` checks each flip with the config's primitives. Room round the
    ends (``flip_end_margin_m``) is kept where a path has it and never costs a flip: the
    flips accepted are those the nominal ends allow, and only some of them keep the room."""
    from inhand_exp.bench.cli import load_config
    from inhand_exp.bench.flips import flip_conditions

    nominal = flip_conditions(load_config("pole", ["primitives.flip_end_margin_m=0"]), 20, 0)
    wider = flip_conditions(load_config("pole", ["primitives.flip_end_margin_m=0.025"]), 20, 0)
    assert nominal["checked"] == wider["checked"]
    assert nominal["accepted"] == wider["accepted"] > 0
    assert nominal["accepted_with_end_margin"] == 0
    assert 0 < wider["accepted_with_end_margin"] < wider["accepted"]


def test_reach_splits_the_cube_goals_by_posture(capsys):
    """The cube study's start; the goals its posture holds and the others, each with how many
    the search reaches."""
    main(["reach", "--object", "cube", "--pairs", "4", "--resolution-m", "0.04",
          "--resolution-rad", "0.2", "goals=hard", "goals.hard_goal_posture=any",
          "goals.x0=[0.0,0.25,0.0]"])  # a lattice four times coarser than the default's
    out = last_json(capsys)
    assert sum(out["goals"].values()) == out["pairs"] == 4
    for k, n in out["goals"].items():
        assert 0 <= out["reached"][k] <= n
    lo, hi = out["angles_rad"]
    assert lo < 0.0 < hi and out["three_finger_states"] <= out["states"]
    with pytest.raises(SystemExit, match="set goals.x0"):
        main(["reach", "--object", "cube"])
    with pytest.raises(SystemExit):
        main(["reach", "--object", "cube", "--resolution-rad", "0"])
    assert "--resolution-rad must be > 0" in capsys.readouterr().err


def test_fingerprint_repeats_and_tells_a_changed_run_apart(capsys, tmp_path):
    kept = tmp_path / "run.npz"
    main(["fingerprint", "--actions", "6", "--out", str(kept)])
    first = last_json(capsys)
    main(["fingerprint", "--actions", "6", "--against", str(kept)])
    again = last_json(capsys)
    assert again["fingerprint"] == first["fingerprint"] and sum(first["outcomes"].values()) == 6
    assert again["against"] == {"masks_differing": 0, "outcomes_differing": 0,
                                "max_pose_diff": 0.0}
    main(["fingerprint", "--actions", "6", "--seed", "1"])
    assert last_json(capsys)["fingerprint"] != first["fingerprint"]
    # the torque law at every physics step: other states, so another fingerprint
    main(["fingerprint", "--actions", "6", "--against", str(kept), "sim.control_substeps=1"])
    changed = last_json(capsys)
    assert changed["fingerprint"] != first["fingerprint"]
    assert changed["against"]["max_pose_diff"] > 0.0


def test_fingerprint_refuses_a_run_of_another_length_or_a_foreign_file(capsys, tmp_path):
    kept = tmp_path / "run.npz"
    main(["fingerprint", "--actions", "3", "--out", str(kept)])
    with pytest.raises(SystemExit, match="holds 3 actions, this run plays 4"):
        main(["fingerprint", "--actions", "4", "--against", str(kept)])
    junk = tmp_path / "junk.npz"
    junk.write_text("not numpy\n")
    with pytest.raises(SystemExit, match="not a fingerprint run kept with --out"):
        main(["fingerprint", "--actions", "3", "--against", str(junk)])
