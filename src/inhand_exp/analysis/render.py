"""``inhand-render RUN.mcap [--episode N] [-o FILE.gif|FILE.mp4] [--fps F] [--snapshots K]``:
replay one evaluation episode from its ``/sim/state`` messages.

Each frame draws what the simulator held at that time: the palm, each finger's two links from
its joint angles (forward kinematics of the run's own hand config), the fingertips, the
simulated object (the nominal one scaled by the run's perturbation) at its pose, the contact
forces, and the goal pose as a dashed outline; the title gives the time and, at the end, the
episode's outcome. GIF needs nothing more (Pillow); MP4 needs ``ffmpeg`` on the PATH.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import logging
import math
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
logging.getLogger("matplotlib").setLevel(logging.WARNING)  # no "Animation.save using" line
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Polygon  # noqa: E402
from PIL import Image  # noqa: E402

from inhand_exp.control.grasp import rotation  # noqa: E402
from inhand_exp.record.reader import LogError, read_log  # noqa: E402
from inhand_exp.record.scene import finger_points  # noqa: E402


class RenderError(ValueError):
    """Nothing to render: no such episode, no states, a run log without its config."""


def box(pose, length: float, width: float) -> np.ndarray:
    """Corners (4, 2) of the object at ``pose``: long axis along its local z."""
    hx, hz = width / 2, length / 2
    local = np.array([[-hx, -hz], [hx, -hz], [hx, hz], [-hx, hz]])
    return np.asarray(pose[:2]) + local @ rotation(pose[2]).T


def episode_frames(path: Path, episode: int | None) -> tuple[dict, list[dict], dict | None]:
    """The run's config, the episode's ``/sim/state`` messages and its ``/eval/episode``."""
    try:
        log = read_log(path, topics=("/run/config", "/sim/state", "/eval/episode"))
    except LogError as err:
        raise RenderError(f"{path}: not a run log ({err})") from None
    configs = log.topic("/run/config")
    if not configs:
        raise RenderError(f"{path}: no /run/config message: not a run log of inhand-exp")
    states = log.topic("/sim/state")
    if not states:
        raise RenderError(f"{path}: no /sim/state messages (log.sim_state_hz was 0, or the run "
                          f"did not evaluate)")
    have = sorted({m["episode"] for m in states})
    ep = have[0] if episode is None else episode
    if ep not in have:
        raise RenderError(f"{path}: no states of episode {ep}; episodes with states: "
                          f"{have[0]}..{have[-1]} ({len(have)})")
    frames = sorted((m for m in states if m["episode"] == ep), key=lambda m: m["sim_time_s"])
    # the last result of that number: a demo log holds every group's episodes 0..N-1 but the
    # states of its last group only
    result = next((m for m in reversed(log.topic("/eval/episode")) if m["episode"] == ep), None)
    return configs[0]["config"], frames, result


MAX_FRAMES = 300  # a replay longer than this many states plays as a time-lapse


def render(path: Path, episode: int | None = None, out: Path | None = None,
           fps: float = 20.0, snapshots: int = 0, max_frames: int = MAX_FRAMES) -> Path:
    """Write the episode's replay to ``out`` (default: ``episode-N.gif`` beside the log), and
    ``snapshots`` PNG stills evenly spaced over it (``<out>-t<time>s.png``). An episode of more
    than ``max_frames`` logged states (0: no limit) is drawn from that many, evenly spaced, the
    first and the last among them: a long episode is a time-lapse, not a minutes-long GIF."""
    cfg, frames, result = episode_frames(path, episode)
    lapse = 1.0
    if 0 < max_frames < len(frames):
        lapse = (len(frames) - 1) / max(max_frames - 1, 1)
        frames = [frames[int(k)] for k in np.linspace(0, len(frames) - 1, max_frames).round()]
    ep = frames[0]["episode"]
    out = out or path.parent / f"episode-{ep}.gif"
    suffix = out.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise RenderError(f"{out}: the output must be a .gif or a .mp4")
    if suffix == ".mp4" and shutil.which("ffmpeg") is None:
        raise RenderError("MP4 needs ffmpeg on the PATH; write a .gif instead")
    hand, obj, p = cfg["hand"], cfg["object"], cfg.get("perturb", {})
    length = obj["length_m"] * p.get("length_scale", 1.0)
    width = obj["width_m"] * p.get("width_scale", 1.0)
    bases, base_z = hand["finger_base_x_m"], hand["base_z_m"]
    l1, l2 = hand["link_lengths_m"]
    r = hand["tip_radius_m"]

    fig, ax = plt.subplots(figsize=(5, 6))
    ax.set_aspect("equal")
    span = max(abs(b) for b in bases) + hand.get("palm_overhang_m", 0.06) + 0.05
    ax.set_xlim(-span, span)
    ax.set_ylim(base_z - hand.get("palm_thickness_m", 0.02) - 0.02, base_z + l1 + l2 + 0.3)
    ax.axhspan(base_z - hand.get("palm_thickness_m", 0.02), base_z, color="0.6")  # the palm
    if result is not None:
        ax.add_patch(Polygon(box(result["xg"], length, width), fill=False, ls="--", ec="green",
                             label="goal"))
    body = ax.add_patch(Polygon(box(frames[0]["object_pose"], length, width), fc="tan",
                                ec="saddlebrown"))
    links = [ax.plot([], [], "-o", color="steelblue", lw=4, ms=4)[0] for _ in bases]
    tips = [plt.Circle((0, 0), r, color="navy") for _ in bases]
    for t in tips:
        ax.add_patch(t)
    forces = ax.quiver(np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), color="red",
                       angles="xy", scale_units="xy", scale=100.0)
    title = ax.set_title("")

    def draw(k: int):
        m = frames[k]
        body.set_xy(box(m["object_pose"], length, width))
        q = m["joint_q"]
        for i, bx in enumerate(bases):
            pts = finger_points(q[2 * i:2 * i + 2], bx, base_z, l1, l2)
            links[i].set_data(pts[:, 0], pts[:, 1])
            tips[i].center = pts[2]
        xy, uv = np.zeros((3, 2)), np.zeros((3, 2))
        th = m["object_pose"][2]
        for c in m["contacts"]:  # the normal force, drawn along the line to the object centre
            xy[c["finger"]] = c["position"]
            d = np.array(m["object_pose"][:2]) - np.array(c["position"])
            n = d / (np.linalg.norm(d) + 1e-9)
            uv[c["finger"]] = n * c["normal_force_n"]
        forces.set_offsets(xy)
        forces.set_UVC(uv[:, 0], uv[:, 1])
        text = f"episode {ep}   t = {m['sim_time_s']:.2f} s   theta = {math.degrees(th):.0f} deg"
        if lapse > 1:
            text += f"   (x{lapse:.1f})"
        if result is not None and k == len(frames) - 1:
            outcome = "success" if result["success"] else (
                "dropped" if result["dropped"] else "timeout")
            text += f"   {outcome}"
        title.set_text(text)
        return [body, *links, *tips, forces, title]

    stills = set(np.linspace(0, len(frames) - 1, snapshots).round().astype(int).tolist()
                 if snapshots else [])

    def with_stills() -> Iterator[np.ndarray]:
        for k, rgba in enumerate(blitted(fig, [body, *links, *tips, forces, title], draw,
                                         len(frames))):
            if k in stills:
                Image.fromarray(rgba).save(
                    out.with_name(f"{out.stem}-t{frames[k]['sim_time_s']:06.2f}s.png"))
            yield rgba

    try:
        if suffix == ".gif":  # palette images made frame by frame: a quarter of the memory,
            # by the fast octree (4 ms a frame) rather than Pillow's default median cut (22 ms)
            images = [Image.fromarray(rgba[..., :3]).quantize(
                256, method=Image.Quantize.FASTOCTREE) for rgba in with_stills()]
            images[0].save(out, save_all=True, append_images=images[1:], loop=0,
                           duration=round(1000 / fps))
        else:
            mp4(with_stills(), out, fps)
    finally:
        plt.close(fig)
    return out


def blitted(fig, moving: list, draw, n: int) -> Iterator[np.ndarray]:
    """The ``n`` frames as RGBA arrays. Everything that does not move (axes, ticks, palm, goal)
    is drawn once; each frame restores that background and draws only the ``moving`` artists
    that ``draw(k)`` updates. Drawing the whole figure per frame, as ``FuncAnimation.save``
    does (twice over, on Agg), spent most of a replay's time on the axes' ticks."""
    canvas = fig.canvas
    for artist in moving:
        artist.set_animated(True)  # left out of the full draw below
    canvas.draw()
    background = canvas.copy_from_bbox(fig.bbox)
    for k in range(n):
        canvas.restore_region(background)
        for artist in draw(k):
            fig.draw_artist(artist)
        yield np.asarray(canvas.buffer_rgba()).copy()


def mp4(frames: Iterator[np.ndarray], out: Path, fps: float) -> None:
    """Stream the RGBA frames to ``ffmpeg`` as raw video, one at a time (H.264, yuv420p:
    plays everywhere)."""
    first = next(frames)
    h, w = first.shape[:2]
    cmd = ["ffmpeg", "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgba",
           "-s", f"{w}x{h}", "-r", f"{fps:g}", "-i", "-", "-vf",
           "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-vcodec", "libx264", "-pix_fmt", "yuv420p",
           str(out)]
    with tempfile.TemporaryFile() as said:  # a file: ffmpeg never blocks on a full pipe
        proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                stderr=said)
        try:
            with contextlib.suppress(BrokenPipeError):  # ffmpeg stopped early: it says why
                for frame in itertools.chain([first], frames):
                    proc.stdin.write(frame.tobytes())
        finally:
            with contextlib.suppress(BrokenPipeError):
                proc.stdin.close()
            proc.wait()
        if proc.returncode != 0:
            said.seek(0)
            raise RenderError(f"ffmpeg failed writing {out}: "
                              f"{said.read().decode(errors='replace').strip()}")

def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="inhand-render", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("log", type=Path, help="a run.mcap with /sim/state messages")
    parser.add_argument("--episode", type=int, default=None,
                        help="episode number (default: the first with states)")
    parser.add_argument("-o", "--output", type=Path, default=None, help="FILE.gif or FILE.mp4")
    parser.add_argument("--fps", type=float, default=20.0)
    parser.add_argument("--max-frames", type=int, default=MAX_FRAMES,
                        help="draw a longer episode from this many states, evenly spaced (a "
                             "time-lapse); 0: every logged state")
    parser.add_argument("--snapshots", type=int, default=0,
                        help="also write this many PNG stills, evenly spaced")
    args = parser.parse_args(argv)
    if args.snapshots < 0 or not args.fps > 0 or args.max_frames < 0 or args.max_frames == 1:
        parser.error("--snapshots must be >= 0, --fps > 0 and --max-frames 0 or >= 2")
    if not args.log.is_file():
        print(f"inhand-render: {args.log}: no such file", file=sys.stderr)
        raise SystemExit(2)
    try:
        out = render(args.log, args.episode, args.output, args.fps, args.snapshots,
                     args.max_frames)
    except RenderError as err:
        print(f"inhand-render: {err}", file=sys.stderr)
        raise SystemExit(2) from None
    print(f"episode replay written to {out}")
