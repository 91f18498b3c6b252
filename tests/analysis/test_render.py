"""inhand-render: an evaluation episode's /sim/state messages become an animated GIF."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from inhand_exp.analysis.render import RenderError, main, render
from inhand_exp.record import RunLog

APP = [sys.executable, "-c", "from inhand_exp.cli import main; main()"]


@pytest.fixture(scope="module")
def eval_log(tmp_path_factory):
    """A tiny trained-and-evaluated run that recorded its states."""
    tmp = tmp_path_factory.mktemp("render")
    res = subprocess.run([*APP, "mode=train_eval", "train.frames=8", "learner.frames_per_batch=8",
                          "learner.minibatch_size=4", "train.num_envs=2",
                          "train.backend=serial", "learner.epochs=1", "eval.episodes=2",
                          "task.max_actions=3", "goals=easy", f"hydra.run.dir={tmp / 'run'}"],
                         cwd=tmp, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    return tmp / "run" / "run.mcap"


def test_an_episode_becomes_a_gif_whose_frames_differ_and_png_stills(eval_log, tmp_path):
    out = render(eval_log, episode=1, out=tmp_path / "ep.gif", fps=10, snapshots=3)
    with Image.open(out) as gif:
        assert gif.n_frames > 5 and gif.size[0] > 100
        gif.seek(0)
        first = np.asarray(gif.convert("RGB")).copy()
        gif.seek(gif.n_frames - 1)
        last = np.asarray(gif.convert("RGB"))
    assert (first != last).any()  # the hand and the object moved
    assert len(list(tmp_path.glob("ep-t*.png"))) == 3


def test_refusals_name_the_problem(eval_log, tmp_path, capsys):
    with pytest.raises(RenderError, match="no states of episode 7; episodes with states: 0..1"):
        render(eval_log, episode=7, out=tmp_path / "x.gif")
    with pytest.raises(RenderError, match="must be a .gif or a .mp4"):
        render(eval_log, episode=0, out=tmp_path / "x.avi")
    with RunLog(tmp_path / "bare.mcap"):
        pass
    with pytest.raises(RenderError, match="no /run/config"):
        render(tmp_path / "bare.mcap")
    (tmp_path / "junk.mcap").write_text("junk")
    with pytest.raises(SystemExit) as end:
        main([str(tmp_path / "junk.mcap")])
    assert end.value.code == 2 and "not a run log" in capsys.readouterr().err


def test_the_log_draws_its_episodes_on_a_foxglove_scene(eval_log):
    from mcap.reader import make_reader

    from inhand_exp.record import read_log

    log = read_log(eval_log)
    states = log.topic("/sim/state")
    scenes = [m for m in log.messages if m.topic == "/scene"]
    assert len(scenes) == len(states) > 0  # both episodes (log.scene_episodes is 10)
    objects = [next(e for e in m.data["entities"] if e["id"] == "object") for m in scenes]
    poses = sorted(((s["episode"], s["sim_time_s"]), s["object_pose"]) for s in states)
    drawn = [o["cubes"][0]["pose"]["position"] for o in objects]
    np.testing.assert_allclose(sorted((p["x"], p["z"]) for p in drawn),
                               sorted((x, z) for _, (x, z, _) in poses))
    times = [m.log_time_ns for m in scenes]
    assert times == sorted(times)  # one episode after the other
    with open(eval_log, "rb") as f:
        summary = make_reader(f).get_summary()
    names = {summary.schemas[c.schema_id].name for c in summary.channels.values()
             if c.topic == "/scene"}
    assert names == {"foxglove.SceneUpdate"}  # what Foxglove's 3D panel looks for
