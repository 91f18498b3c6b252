"""inhand-render: an evaluation episode's /sim/state messages become an animated GIF."""

from __future__ import annotations

import os
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


def test_a_long_episode_becomes_a_time_lapse_of_at_most_max_frames(eval_log, tmp_path):
    full = render(eval_log, episode=1, out=tmp_path / "full.gif", max_frames=0)
    with Image.open(full) as gif:
        assert gif.n_frames > 8
    short = render(eval_log, episode=1, out=tmp_path / "short.gif", max_frames=6)
    with Image.open(short) as gif:
        assert gif.n_frames == 6
        first = np.asarray(gif.convert("RGB")).copy()
        gif.seek(5)
        last = np.asarray(gif.convert("RGB"))
    assert (first != last).any()  # still the episode's motion, from its first state to its last


def test_a_demo_logs_replay_takes_the_result_of_the_group_whose_states_it_holds(tmp_path,
                                                                               compose_cfg):
    """A demo log has episode 0 of every group, and states of its last group (hard) only: the
    goal and outcome drawn are the hard episode's, not the easy one's."""
    from inhand_exp.analysis.render import episode_frames
    from inhand_exp.runinfo import run_config_message

    path = tmp_path / "run.mcap"
    with RunLog(path) as log:
        log.write("/run/config", run_config_message(compose_cfg(), tmp_path, []))
        for group, win in (("easy", True), ("hard", False)):
            log.write("/eval/episode", {
                "episode": 0, "group": group, "success": win, "dropped": False,
                "timeout": not win, "sim_time_s": 1.0, "n_actions": 1, "n_invalid": 0,
                "x0": [0.0, 0.3, 0.0], "xg": [0.01 if win else -0.02, 0.3, 0.0],
                "final_pose": [0.0, 0.3, 0.0]})
        for t in (0.0, 0.5):
            log.write("/sim/state", {"episode": 0, "sim_time_s": t,
                                     "object_pose": [0.0, 0.3, 0.0], "joint_q": [0.0] * 6,
                                     "joint_qd": [0.0] * 6, "contacts": []})
    _, frames, result = episode_frames(path, 0)
    assert len(frames) == 2 and result["group"] == "hard" and result["xg"][0] == -0.02


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


def test_a_blitted_frame_is_the_figure_drawn_whole():
    """Only the moving artists are drawn per frame, over the background drawn once: no trace
    of the frame before remains, so each frame equals a full draw of the same state."""
    import matplotlib.pyplot as plt

    from inhand_exp.analysis.render import blitted

    fig, ax = plt.subplots(figsize=(2, 2))
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    (line,) = ax.plot([], [], lw=3)
    title = ax.set_title("")

    def draw(k):
        line.set_data([0.1 * k, 0.5], [0.2, 0.1 * k])
        title.set_text(f"frame {k}")
        return [line, title]

    frames = list(blitted(fig, [line, title], draw, 4))
    assert not (frames[0] == frames[3]).all()
    line.set_animated(False)
    title.set_animated(False)
    draw(3)
    fig.canvas.draw()
    np.testing.assert_array_equal(frames[3], np.asarray(fig.canvas.buffer_rgba()))
    plt.close(fig)


def test_an_mp4_gets_every_frame_through_ffmpeg(eval_log, tmp_path, monkeypatch):
    """ffmpeg reads the frames as raw RGBA of the figure's size (a stand-in ffmpeg on the PATH
    keeps what it was given)."""
    fake = tmp_path / "bin" / "ffmpeg"
    fake.parent.mkdir()
    fake.write_text('#!/bin/bash\necho "$@" > "$(dirname "$0")/args"\ncat > "${@: -1}"\n')
    fake.chmod(0o755)
    monkeypatch.setenv("PATH", f"{fake.parent}:{os.environ['PATH']}")
    out = render(eval_log, episode=1, out=tmp_path / "ep.mp4", max_frames=6)
    args = (fake.parent / "args").read_text().split()
    w, h = map(int, args[args.index("-s") + 1].split("x"))
    assert args[args.index("-pix_fmt") + 1] == "rgba" and w > 100 and h > 100
    assert out.stat().st_size == 6 * w * h * 4
    fake.write_text("#!/bin/sh\necho 'Unknown encoder libx264' >&2\nexit 1\n")
    with pytest.raises(RenderError, match="ffmpeg failed writing .*Unknown encoder libx264"):
        render(eval_log, episode=1, out=tmp_path / "ep.mp4", max_frames=6)
