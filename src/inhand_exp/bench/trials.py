"""Benchmark trials of the primitives: one seeded trial = a grasp, a primitive, a judged outcome.

Every outcome is judged from the simulated state (poses from the object's joints, contact
coordinates from the fingertips' simulated positions, faces from PyBullet's contact normals),
never from what the controller was asked to do.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from omegaconf import DictConfig

from inhand_exp.config import NoiseConfig, PerturbConfig
from inhand_exp.control.execute import Observation, execute
from inhand_exp.control.flip import Flip
from inhand_exp.control.grasp import Contacts, face_axes, rotation
from inhand_exp.control.hand import GeometryError
from inhand_exp.control.release_land import Land, Release
from inhand_exp.control.repose import Repose
from inhand_exp.control.sample import Workspace, pinch_grasp, random_grasp
from inhand_exp.control.slide import Slide
from inhand_exp.sim.world import wrap_angle
from inhand_exp.task.scene import build_scene

HOLD_S = 10.0
HOLD_TOL = (0.001, 0.01)  # m, rad
REPOSE_TOL = (0.002, 0.02)
SLIDE_TOL_M = 0.003


@dataclass
class Trial:
    """One judged trial: success, drop, final errors (m, rad), simulated and wall time (s)."""

    success: bool
    dropped: bool
    err_m: float
    err_rad: float
    sim_s: float
    wall_s: float


class Bench:
    """A world and the controllers' model for one object, perturbation and noise setting."""

    def __init__(self, cfg: DictConfig, perturb: PerturbConfig | None = None,
                 noise: tuple[float, float] = (0.0, 0.0)):
        self.cfg = cfg
        self.scene = build_scene(cfg, perturb, NoiseConfig("bench", *noise))
        self.world, self.model = self.scene.world, self.scene.model  # nominal: the controllers'
        self.true_model = self.scene.true_model  # the simulated object: to touch its surface
        self.workspace, self.prim = self.scene.workspace, self.scene.prim

    def start(self, rng: np.random.Generator, pinch: int | None = None,
              workspace: Workspace | None = None, tries: int = 4000) -> Contacts:
        """Reset the world at a random valid grasp of the simulated object; with ``pinch``, one
        where the other two fingers could hold it alone (``sample.pinch_grasp``)."""
        ws = workspace or self.workspace
        if pinch is None:
            pose, contacts, q = random_grasp(self.true_model, rng, ws)
        else:
            pose, contacts, q = pinch_grasp(self.true_model, rng, pinch, ws, max_tries=tries)
        self.world.reset(pose, q)
        return contacts

    def offset(self, rng: np.random.Generator) -> np.ndarray:
        """Observation error on the object pose, held for one primitive."""
        return rng.uniform(-self.scene.noise, self.scene.noise)

    def observe(self) -> Observation:
        pose, twist = self.world.object_state()
        q, qd = self.world.joint_state()
        return Observation(q, qd, pose, twist, 0.0)

    def coords(self) -> np.ndarray:
        """Simulated contact coordinate of each fingertip along the object's long axis (m)."""
        pose = self.world.object_pose()
        return (self.world.tip_positions() - pose[:2]) @ rotation(pose[2])[:, 1]

    def faces(self) -> dict[int, float]:
        """Per finger in contact: the sign of the contact normal across the pole (+1: pushes
        towards +O_x, i.e. the finger is on the left face)."""
        pose = self.world.object_pose()
        across = rotation(pose[2])[:, 0]
        return {c.finger: float(np.sign(c.normal @ across)) for c in self.world.contacts()}


def _pose_error(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    return float(np.hypot(*(a[:2] - b[:2]))), abs(wrap_angle(float(a[2] - b[2])))


def hold(b: Bench, rng: np.random.Generator) -> Trial:
    contacts = b.start(rng)
    start = b.world.object_pose()
    t = time.perf_counter()
    out = execute(b.world, Repose(b.model, contacts, np.zeros(3), HOLD_S, b.prim),
                  b.offset(rng))
    em, er = _pose_error(b.world.object_pose(), start)
    ok = out.ok and em <= HOLD_TOL[0] and er <= HOLD_TOL[1]
    return Trial(ok, out.dropped, em, er, out.sim_time_s, time.perf_counter() - t)


def _unit_reposes(b: Bench) -> list[np.ndarray]:
    dx, dz, dth = b.prim.repose_dx_m, b.prim.repose_dz_m, b.prim.repose_dtheta_rad
    return [np.array(v) for v in ([dx, 0, 0], [-dx, 0, 0], [0, dz, 0], [0, -dz, 0],
                                  [0, 0, dth], [0, 0, -dth])]


def _feasible(primitive, obs: Observation, offset: np.ndarray | None = None) -> bool:
    """The primitive's own check, on the pose as observed (with the trial's held error)."""
    if offset is not None:
        obs = Observation(obs.q, obs.qd, obs.pose + offset, obs.twist, 0.0)
    return primitive.start(obs) is None


def repose(b: Bench, rng: np.random.Generator) -> Trial | None:
    """A random feasible unit repose from a random grasp (None if none is feasible)."""
    contacts = b.start(rng)
    offset = b.offset(rng)
    for k in rng.permutation(6):
        delta = _unit_reposes(b)[k]
        prim = Repose(b.model, contacts, delta, b.prim.repose_duration_s, b.prim)
        if _feasible(prim, b.observe(), offset):
            break
    else:
        return None
    start = b.world.object_pose()
    t = time.perf_counter()
    out = execute(b.world, prim, offset, settle_early=b.prim.settle_early)
    em, er = _pose_error(b.world.object_pose(), start + delta)
    ok = out.ok and em <= REPOSE_TOL[0] and er <= REPOSE_TOL[1]
    return Trial(ok, out.dropped, em, er, out.sim_time_s,
                 time.perf_counter() - t)


def slide(b: Bench, rng: np.random.Generator) -> Trial | None:
    """A random feasible slide of one finger by the configured step."""
    contacts = b.start(rng)
    dc = b.prim.slide_dc_m
    offset = b.offset(rng)
    for k in rng.permutation(6):
        finger, sign = int(k // 2), (1 if k % 2 == 0 else -1)
        prim = Slide(b.model, contacts, finger, sign * dc, b.prim.slide_duration_s, b.prim)
        if _feasible(prim, b.observe(), offset):
            break
    else:
        return None
    before = b.coords()
    t = time.perf_counter()
    out = execute(b.world, prim, offset, settle_early=b.prim.settle_early)
    moved = b.coords() - before
    err = abs(float(moved[finger]) - sign * dc)
    in_contact = finger in b.faces()
    ok = out.ok and err <= SLIDE_TOL_M and in_contact
    return Trial(ok, out.dropped, err, 0.0, out.sim_time_s,
                 time.perf_counter() - t)


def flip(b: Bench, rng: np.random.Generator, finger: int, max_grasps: int = 200,
         min_tilt: float = 0.0) -> Trial | None:
    """A flip of ``finger`` from a random pinch grasp (tilted at least ``min_tilt`` rad from
    upright, to either side) where the flip's own check allows it. Tilted pinches are rare
    and their flips rarer: that search is cut to 20 grasps of at most 100 draws each."""
    ws, tries = b.workspace, 4000
    offset = b.offset(rng)
    if min_tilt > 0:
        max_grasps, tries = min(max_grasps, 20), 100
    for _ in range(max_grasps):
        if min_tilt > 0:
            side = 1 if rng.random() < 0.5 else -1
            lo, hi = sorted((side * min_tilt, side * max(abs(ws.low[2]), abs(ws.high[2]))))
            ws = Workspace((ws.low[0], ws.low[1], lo), (ws.high[0], ws.high[1], hi))
        try:
            contacts = b.start(rng, pinch=finger, workspace=ws, tries=tries)
        except GeometryError:  # no pinch grasp found in this part of the workspace
            continue
        prim = Flip(b.model, contacts, finger, b.prim.flip_duration_s, b.prim)
        if _feasible(prim, b.observe(), offset):
            break
    else:
        return None
    before = b.faces().get(finger, 0.0)
    start = b.world.object_pose()
    t = time.perf_counter()
    out = execute(b.world, prim, offset)
    after = b.faces()
    em, er = _pose_error(b.world.object_pose(), start)
    ok = out.ok and len(after) == 3 and after.get(finger, before) == -before
    return Trial(ok, out.dropped, em, er, out.sim_time_s,
                 time.perf_counter() - t)


def _releasable(b: Bench, rng: np.random.Generator) -> tuple[int, Release] | None:
    """A random grasp and a random finger whose release the primitive's own check allows."""
    contacts = b.start(rng)
    for finger in rng.permutation(3):
        prim = Release(b.model, contacts, int(finger), b.prim.release_duration_s, b.prim)
        if _feasible(prim, b.observe()):
            return int(finger), prim
    return None


def release(b: Bench, rng: np.random.Generator) -> Trial | None:
    """A release of one finger while the other two hold the object."""
    found = _releasable(b, rng)
    if found is None:
        return None
    finger, prim = found
    start = b.world.object_pose()
    t = time.perf_counter()
    out = execute(b.world, prim, b.offset(rng))
    touching = set(b.faces())
    em, er = _pose_error(b.world.object_pose(), start)
    ok = out.ok and finger not in touching and len(touching) == 2
    return Trial(ok, out.dropped, em, er, out.sim_time_s,
                 time.perf_counter() - t)


def land(b: Bench, rng: np.random.Generator, other_elbow: bool = False) -> Trial | None:
    """Land on another face after a successful release (the release itself is not scored
    here); with ``other_elbow``, on any face with the elbow on the other side, which it must
    end with."""
    found = _releasable(b, rng)
    if found is None or not execute(b.world, found[1]).ok:
        return None
    finger, released = found
    prim = Land(b.model, released.result, finger, b.prim.land_duration_s, b.prim,
                other_elbow=other_elbow)
    if not _feasible(prim, b.observe()):
        return None
    elbow = b.world.joint_state()[0][2 * finger + 1] >= 0
    start = b.world.object_pose()
    t = time.perf_counter()
    out = execute(b.world, prim, b.offset(rng))
    pose = b.world.object_pose()
    em, er = _pose_error(pose, start)
    # the landed finger pushes on its new face (PyBullet's contact normal), the others hold on
    inward = rotation(pose[2]) @ face_axes(prim.face)[0]
    on_face = any(c.finger == finger and float(c.normal @ inward) > 0.95
                  for c in b.world.contacts())
    ok = out.ok and len(b.faces()) == 3 and on_face
    if other_elbow:
        ok = ok and (b.world.joint_state()[0][2 * finger + 1] >= 0) != elbow
    return Trial(ok, out.dropped, em, er, out.sim_time_s,
                 time.perf_counter() - t)
