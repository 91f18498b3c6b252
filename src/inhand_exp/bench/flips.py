"""How often a flip is possible: the flip's own check (``Flip.start``) on random held states.

Each trial draws a pose of the workspace and a grasp that holds it (``sample.random_grasp``),
at rest, and asks each flip of the action table whose staying fingers oppose each other
whether it can start there. The reasons it refuses are counted with their numbers left out,
and the flips accepted that keep ``primitives.flip_end_margin_m`` round the ends (the others
pass the nominal ends) are counted apart.
"""

from __future__ import annotations

import re
from collections import Counter

import numpy as np
from omegaconf import DictConfig

from inhand_exp.config import PrimitivesConfig, typed
from inhand_exp.control.execute import Observation
from inhand_exp.control.flip import Flip
from inhand_exp.control.hand import HandModel
from inhand_exp.control.sample import Workspace, random_grasp
from inhand_exp.task.goals import FLIP_FINGERS


def flip_conditions(cfg: DictConfig, grasps: int, seed: int) -> dict:
    """Counts of accepted flips and of each refusal over ``grasps`` random held states, and
    the object angles (rad) of the states checked and of those accepted, in bins."""
    model = HandModel.from_config(cfg.hand, cfg.object, cfg.sim.gravity_mps2)
    ws = Workspace.from_config(cfg.task)
    gains = typed(cfg.primitives, PrimitivesConfig)
    rng = np.random.default_rng(seed)
    why: Counter[str] = Counter()
    angles, accepted = [], []
    roomy = 0  # accepted flips that keep flip_end_margin_m round the ends
    for _ in range(grasps):
        pose, contacts, q = random_grasp(model, rng, ws)
        for finger in FLIP_FINGERS:
            a, b = (j for j in range(3) if j != finger)
            if contacts.posture.faces[a] == contacts.posture.faces[b]:
                continue  # not offered: the staying pair must oppose
            obs = Observation(q, np.zeros(6), pose, np.zeros(3), 0.0)
            flip = Flip(model, contacts, finger, gains.flip_duration_s, gains)
            refusal = flip.start(obs)
            angles.append(float(pose[2]))
            if refusal is None:
                why["accepted"] += 1
                roomy += flip.end_margin > 0
                accepted.append(float(pose[2]))
            else:
                why[re.sub(r"\[[^\]]*\]|[-+]?\d+(\.\d+)?", "#", refusal)] += 1
    edges = np.linspace(-np.pi / 2, np.pi / 2, 7)
    checked = int(sum(why.values()))
    print(f"{grasps} held states, {checked} flips whose staying fingers oppose; "
          f"{roomy} of the {why['accepted']} accepted keep the end margin "
          f"({gains.flip_end_margin_m * 100:g} cm)")
    for reason, n in why.most_common():
        print(f"{n:6d} {n / max(checked, 1):6.1%}  {reason}")
    return {"grasps": grasps, "checked": checked, "accepted": why["accepted"],
            "accepted_with_end_margin": roomy,
            "reasons": dict(why), "theta_bins": edges.round(3).tolist(),
            "theta_checked": np.histogram(angles, edges)[0].tolist(),
            "theta_accepted": np.histogram(accepted, edges)[0].tolist()}
