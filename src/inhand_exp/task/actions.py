"""The discrete mid-level actions (paper Table I), generated from the ``primitives`` config.

Pole: repose +-x, +-z, +-theta; slide +-dC for each finger; flip left (finger 0) and flip right
(finger 2): 14 actions. Cube: the 6 reposes, then release and land for each finger: 12 actions;
with ``land_other_elbow``, then a land with the elbow on the other side for each finger: 15.
Each action becomes a fresh primitive for the current contact configuration; a primitive's
``start`` is its own feasibility check (inverse kinematics, joint limits, force distribution).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from inhand_exp.config import PrimitivesConfig
from inhand_exp.control.execute import Observation, Primitive
from inhand_exp.control.flip import Flip
from inhand_exp.control.grasp import Contacts
from inhand_exp.control.hand import HandModel
from inhand_exp.control.release_land import Land, Release
from inhand_exp.control.repose import Repose
from inhand_exp.control.slide import Slide


@dataclass(frozen=True)
class Action:
    """One discrete action: its kind, name and parameters (SI units)."""

    index: int
    kind: str  # repose, slide, flip, release, land
    name: str
    delta: tuple[float, float, float] = (0.0, 0.0, 0.0)  # repose: (dx m, dz m, dtheta rad)
    finger: int = -1
    dc: float = 0.0  # slide: m along the face
    other_elbow: bool = False  # land: with the elbow on the other side


def action_table(prim) -> tuple[Action, ...]:
    """The actions the ``primitives`` config offers, in a fixed order."""
    dx, dz, dth = prim.repose_dx_m, prim.repose_dz_m, prim.repose_dtheta_rad
    specs: list[dict] = [
        dict(kind="repose", name=name, delta=delta) for name, delta in (
            ("repose +x", (dx, 0.0, 0.0)), ("repose -x", (-dx, 0.0, 0.0)),
            ("repose +z", (0.0, dz, 0.0)), ("repose -z", (0.0, -dz, 0.0)),
            ("repose +theta", (0.0, 0.0, dth)), ("repose -theta", (0.0, 0.0, -dth)))]
    if prim.slide:
        specs += [dict(kind="slide", name=f"slide finger {i} {'+' if s > 0 else '-'}",
                       finger=i, dc=s * prim.slide_dc_m) for i in range(3) for s in (1, -1)]
    if prim.flip:
        specs += [dict(kind="flip", name="flip left", finger=0),
                  dict(kind="flip", name="flip right", finger=2)]
    if prim.release_land:
        specs += [dict(kind="release", name=f"release finger {i}", finger=i) for i in range(3)]
        specs += [dict(kind="land", name=f"land finger {i}", finger=i) for i in range(3)]
        if prim.land_other_elbow:
            specs += [dict(kind="land", name=f"land finger {i} other elbow", finger=i,
                           other_elbow=True) for i in range(3)]
    return tuple(Action(index=k, **spec) for k, spec in enumerate(specs))


def flip_actions(actions: tuple[Action, ...]) -> frozenset[int]:
    """The indices of the actions that move a finger to another face: the flips, and the lands
    that end the cube's release-and-land."""
    return frozenset(a.index for a in actions if a.kind in ("flip", "land"))


def undo_actions(actions: tuple[Action, ...], moves: bool = True,
                 flips: bool = False) -> tuple[int | None, ...]:
    """For each action, the index of the one that undoes it, or None (releases and lands).

    ``moves``: a repose is undone by the opposite repose, a slide by the same finger's slide
    back. ``flips``: a flip by the same flip (the object holds still during a flip and the
    finger lands nearest its present coordinate, so a second flip carries it back to about
    where it was).
    """
    def undoes(a: Action, b: Action) -> bool:
        if a.kind != b.kind:
            return False
        if a.kind == "flip":
            return flips and a.finger == b.finger
        if a.kind not in ("repose", "slide") or not moves:
            return False
        if a.kind == "repose":
            return all(x == -y for x, y in zip(a.delta, b.delta, strict=True))
        return a.finger == b.finger and a.dc == -b.dc

    return tuple(next((b.index for b in actions if undoes(a, b)), None) for a in actions)


def make_primitive(action: Action, model: HandModel, contacts: Contacts,
                   prim: PrimitivesConfig) -> Primitive:
    """A fresh primitive carrying out ``action`` from ``contacts``, with the durations, gains and
    force limits of ``prim``."""
    if action.kind == "repose":
        return Repose(model, contacts, np.array(action.delta), prim.repose_duration_s, prim)
    if action.kind == "slide":
        return Slide(model, contacts, action.finger, action.dc, prim.slide_duration_s, prim)
    if action.kind == "flip":
        return Flip(model, contacts, action.finger, prim.flip_duration_s, prim)
    if action.kind == "release":
        return Release(model, contacts, action.finger, prim.release_duration_s, prim)
    if action.kind == "land":
        return Land(model, contacts, action.finger, prim.land_duration_s, prim,
                    other_elbow=action.other_elbow)
    raise ValueError(f"unknown action kind {action.kind!r}")


def feasibility(actions: tuple[Action, ...], model: HandModel, contacts: Contacts,
                prim: PrimitivesConfig, obs: Observation) -> tuple[np.ndarray, list]:
    """Which actions the filter allows in ``obs``, and the primitives already planned for them.

    An action is feasible when its primitive's ``start`` accepts the observed state; the
    planned primitive is returned so that carrying the action out needs no second plan. The
    primitives share the grasp plans they make of the same contacts (``Observation.plans``).
    """
    obs = dataclasses.replace(obs, plans={})
    mask = np.zeros(len(actions), dtype=bool)
    planned: list = [None] * len(actions)
    for a in actions:
        p = make_primitive(a, model, contacts, prim)
        if p.start(obs) is None:
            mask[a.index], planned[a.index] = True, p
    return mask, planned
