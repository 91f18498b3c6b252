"""What a run prints: the evaluation table beside the paper's numbers, and the note naming the
policy's training settings that an evaluation does not use."""

from __future__ import annotations

from omegaconf import OmegaConf

from inhand_exp.experiment import paper_row, policy_key, table
from inhand_exp.runinfo import unlike_training

SUMMARY = {"episodes": 500, "success_rate": 0.952, "drop_rate": 0.012, "timeout_rate": 0.036,
           "avg_time_s": 5.71}


def test_table_sets_ours_beside_the_papers_cells_in_aligned_columns(compose_cfg):
    full = table(SUMMARY, compose_cfg("goals=hard"), sampled=False).splitlines()
    assert full[2].split() == ["success", "95.2%", "79.3%"]
    assert full[3].split() == ["drop", "1.2%", "15.7%"]
    # Table III: success only
    sparse = table(SUMMARY, compose_cfg("noise=paper"), sampled=True).splitlines()
    assert sparse[2].split() == ["success", "95.2%", "93.2%"]
    assert sparse[3].split() == ["drop", "1.2%", "-"]
    assert len({len(line) for line in sparse[1:]}) == 1  # every row as wide as the header
    assert "sampled actions" in sparse[0] and "deterministic actions" in full[0]
    assert "training pairs" in table(SUMMARY, compose_cfg("eval.split=train"), True)
    assert "training pairs" not in full[0]
    assert paper_row(compose_cfg("object.name=pole", "perturb=heavier")) is not None
    assert paper_row(compose_cfg("goals=easy", "noise=paper")) is None
    assert paper_row(compose_cfg("object=cube", "goals=hard"))["success_rate"] == "0.714"


def test_a_run_without_successes_shows_no_mean_time(compose_cfg):
    none = {**SUMMARY, "success_rate": 0.0, "avg_time_s": float("nan")}
    rows = table(none, compose_cfg("learner=ddpg", "goals=easy"), sampled=False).splitlines()
    assert rows[5].split() == ["avg", "time", "(s)", "-", "1.82"]


def test_a_policys_store_key_ignores_what_only_the_test_set_uses(compose_cfg):
    """A sweep's evaluations share one policy: the tested group, the hard set's flip share
    and the perturbation leave its key as it is; the training budget or reward changes it."""
    def key(*overrides):
        return policy_key(compose_cfg("goals.train_groups=[easy,medium,hard]", *overrides))

    base = key()
    for test_only in ("goals=hard", "goals.hard_flip_share=0", "goals.test_pairs=100",
                      "perturb=heavier", "eval.episodes=7"):
        assert key(test_only) == base, test_only
    for shaping in ("train.frames=2048", "task.reward_progress=0.1", "goals.seed=5",
                    "goals.train_groups=[medium]", "task.touch_finds_length=true"):
        assert key(shaping) != base, shaping


def test_a_task_option_at_its_default_leaves_the_store_key_as_it_was(compose_cfg, monkeypatch):
    """Adding a task setting to the schema, at its default, must not orphan the policies
    already stored (each costs an hour's training here): the key leaves defaults out."""
    import dataclasses

    from inhand_exp import experiment
    from inhand_exp.config import TaskConfig

    cfg = compose_cfg("goals.train_groups=[easy,medium,hard]")
    before = policy_key(cfg)
    newer = dataclasses.make_dataclass(
        "NewerTask", [("some_new_filter", bool, dataclasses.field(default=False))],
        bases=(TaskConfig,))
    monkeypatch.setattr(experiment, "TaskConfig", newer)
    for value, same in ((False, True), (True, False)):
        grown = OmegaConf.create(OmegaConf.to_container(cfg, resolve=True, enum_to_str=True))
        grown.task.some_new_filter = value
        assert (policy_key(grown) == before) is same, value


def test_the_flagged_rows_say_how_many_episodes_flipped(compose_cfg):
    counted = {**SUMMARY, "needs_flip": 170, "needs_flip_success_rate": 0.3,
               "needs_flip_drop_rate": 0.05, "needs_flip_flipped": 77,
               "needs_flip_flipped_success": 51, "no_flip": 330, "no_flip_success_rate": 0.7,
               "no_flip_drop_rate": 0.04, "no_flip_flipped": 9, "no_flip_flipped_success": 6,
               "lone_down": 0, "flipped": 86, "flipped_success": 57}
    rows = table(counted, compose_cfg("goals=hard"), sampled=False).splitlines()
    assert rows[6].endswith("(170 episodes; drops 5.0%; flipped in 77 (51 solved))")
    assert rows[7].endswith("(330 episodes; drops 4.0%; flipped in 9 (6 solved))")
    assert rows[-1] == "flipped in 86 of the 500 episodes, 57 of them solved"
    older = {k: v for k, v in counted.items() if "flipped" not in k}  # no counts: no mention
    assert "flipped" not in table(older, compose_cfg("goals=hard"), sampled=False)


def test_an_evaluation_names_the_task_settings_its_policy_was_trained_with_otherwise(
        compose_cfg):
    trained = ["task.no_undo=true", "task.filter=mask", "task.reward_progress=0.1",
               "task.max_actions=200", "task.success_tol_m=0.010", "seed=3",
               "'goals.train_groups=[easy,medium,hard]'"]
    # rewards, other groups and values equal as numbers are not differences
    assert unlike_training(compose_cfg(), trained) == ["task.no_undo=true (here: false)"]
    assert unlike_training(compose_cfg("task.no_undo=true", "task.filter=penalty"), trained) \
        == ["task.filter=mask (here: penalty)"]
    assert unlike_training(compose_cfg(), None) == []
    # a setting the training left at its default and this run changes is named too
    assert unlike_training(compose_cfg("task.no_undo=true", "task.no_undo_flip=true",
                                       "task.max_actions=50", "task.reward_goal=1"),
                           ["task.no_undo=true"]) \
        == ["task.no_undo_flip=false (here: true)", "task.max_actions=200 (here: 50)"]
    assert unlike_training(compose_cfg(), []) == []
