"""The controller's model of the hand (three ``FingerModel``) and of the object, from config."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from inhand_exp.config import HandConfig, ObjectConfig
from inhand_exp.control.clearance import (
    lowest_corner,
    point_box_distance,
    segment_box_distance,
    segment_box_distances,
    to_object,
)
from inhand_exp.control.finger import FingerModel
from inhand_exp.control.grasp import BoxShape, Contacts, contact_frames, rotation

# Fraction of the tip radius by which the distal link's capsule is cut short for the clearance
# check: up to there the tip's sphere covers the capsule (a link radius of 2/3 the tip's).
TIP_OVERLAP = 0.75


class GeometryError(ValueError):
    """The hand cannot realise a grasp (a tip out of reach or outside its joint limits, or a
    link that would cut into the object)."""


@dataclass(frozen=True)
class HandModel:
    """Three fingers, their tip radius and the nominal object, as the controllers know them.

    The links are capsules of ``link_radius`` that must keep ``clearance`` of air to the object;
    the palm is the plane z = base z between ``palm_x`` (the object must stay ``clearance``
    above it, and no finger joint or tip goes below it there).
    """

    fingers: tuple[FingerModel, FingerModel, FingerModel]
    tip_radius: float
    shape: BoxShape
    mu: float  # friction coefficient of fingertip on object, as combined by the simulator
    link_radius: float = 0.008
    clearance: float = 0.002
    palm_x: tuple[float, float] = (-math.inf, math.inf)

    @classmethod
    def from_config(cls, hand: HandConfig, obj: ObjectConfig, gravity: float) -> HandModel:
        fingers = tuple(
            FingerModel.build(x, hand.base_z_m, tuple(hand.link_lengths_m),
                              tuple(hand.link_masses_kg), hand.tip_mass_kg, hand.tip_radius_m,
                              tuple(hand.joint_lower_rad), tuple(hand.joint_upper_rad), gravity)
            for x in hand.finger_base_x_m)
        shape = BoxShape(obj.length_m, obj.width_m, obj.mass_kg)
        xs = hand.finger_base_x_m
        model = cls(fingers, hand.tip_radius_m, shape, hand.friction * obj.friction,
                    hand.link_radius_m, hand.link_clearance_m,
                    (xs[0] - hand.palm_overhang_m, xs[-1] + hand.palm_overhang_m))
        model._check_reach(obj)
        return model

    def _check_reach(self, obj: ObjectConfig) -> None:
        reach = [f.l1 + f.l2 for f in self.fingers]
        xs = [f.base_x for f in self.fingers]
        if not xs[0] < xs[1] < xs[2]:
            raise GeometryError(f"hand.finger_base_x_m must increase left to right, got {xs}")
        gap = max(b - a for a, b in zip(xs, xs[1:], strict=False))
        if min(reach) < gap / 2 + self.tip_radius:
            raise GeometryError(f"fingers of reach {min(reach):.3f} m cannot meet between bases "
                                f"{gap:.3f} m apart: the tips cannot hold an object together")

    def lengthened(self, extra_m: float) -> HandModel:
        """The same hand with the object ``extra_m`` longer at each end (a finger passing
        round an end keeps that much more room from it)."""
        if extra_m == 0:
            return self
        shape = BoxShape(self.shape.length_m + 2 * extra_m, self.shape.width_m,
                         self.shape.mass_kg)
        return dataclasses.replace(self, shape=shape)

    def widened(self, extra_m: float) -> HandModel:
        """The same hand with the object ``extra_m`` wider at each long face (negative:
        thinner), to plan on the faces where the fingertips find them; never under a quarter
        of the nominal width."""
        if extra_m == 0:
            return self
        width = max(self.shape.width_m + 2 * extra_m, 0.25 * self.shape.width_m)
        shape = BoxShape(self.shape.length_m, width, self.shape.mass_kg)
        return dataclasses.replace(self, shape=shape)

    def tip_targets(self, contacts: Contacts, pose: np.ndarray) -> np.ndarray:
        """Fingertip centres (3, 2) touching the object at ``contacts`` when it is at ``pose``."""
        pts, nrm = contact_frames(self.shape, contacts, pose)
        return pts - self.tip_radius * nrm

    def grasp_q(self, contacts: Contacts, pose: np.ndarray, press: float = 0.0) -> np.ndarray:
        """Joint angles (6,) placing every tip on its contact, ``press`` metres into the surface.

        Of the two elbow branches, the one whose links stay clear of the object and the palm
        (the larger gap when both do). Raises ``GeometryError`` naming the finger when a
        contact is out of reach or limits, or its links would cut into the object.
        """
        if self.palm_gap(pose) < self.clearance:
            raise GeometryError(f"the object at z = {pose[1]:.3f} m, theta = {pose[2]:.2f} rad "
                                f"would cut into the palm")
        pts, nrm = contact_frames(self.shape, contacts, pose)
        q = np.empty(6)
        for i, finger in enumerate(self.fingers):
            target = pts[i] - (self.tip_radius - press) * nrm[i]
            branches = [qi for qi in (finger.ik(target, e) for e in (1, -1)) if qi is not None]
            if not branches:
                raise GeometryError(f"finger {i} cannot reach its contact at "
                                    f"({target[0]:.3f}, {target[1]:.3f}) m")
            gap, qi = max(((self.finger_gap(i, b, pose), b) for b in branches),
                          key=lambda g: g[0])
            if gap < self.clearance:
                raise GeometryError(f"finger {i}'s links would cut into the object or the palm "
                                    f"to reach its contact ({gap * 1e3:.1f} mm)")
            q[2 * i:2 * i + 2] = qi
        return q

    def palm_gap(self, pose: np.ndarray) -> float:
        """Height of the object's lowest point above the palm (m)."""
        return lowest_corner(pose, self.shape.half_x, self.shape.half_z) - self.fingers[0].base_z

    def finger_gap(self, i: int, qi: np.ndarray, pose: np.ndarray) -> float:
        """Air between finger ``i``'s links (at joint angles ``qi``) and the object at
        ``pose`` (m, 0 or less when they touch); ``-inf`` when a joint or the tip is below the
        palm. The distal link counts up to where the tip's sphere covers it."""
        f = self.fingers[i]
        q1, q12 = float(qi[0]), float(qi[0]) + float(qi[1])
        ex, ez = f.base_x + f.l1 * math.cos(q1), f.base_z + f.l1 * math.sin(q1)
        tx, tz = ex + f.l2 * math.cos(q12), ez + f.l2 * math.sin(q12)
        lo, hi = self.palm_x
        if any(lo <= x <= hi and z < f.base_z for x, z in ((ex, ez), (tx, tz))):
            return -math.inf
        px, pz, c, s = float(pose[0]), float(pose[1]), math.cos(pose[2]), math.sin(pose[2])
        b = to_object(f.base_x, f.base_z, px, pz, c, s)
        e = to_object(ex, ez, px, pz, c, s)
        # the last bit of the distal link lies inside the tip's sphere, which may touch
        inner = (f.l2 - TIP_OVERLAP * self.tip_radius) / f.l2
        t = to_object(ex + inner * (tx - ex), ez + inner * (tz - ez), px, pz, c, s)
        hx, hz = self.shape.half_x, self.shape.half_z
        return min(segment_box_distance(*b, *e, hx, hz),
                   segment_box_distance(*e, *t, hx, hz)) - self.link_radius

    def free_finger_gap(self, i: int, qi: np.ndarray, pose: np.ndarray) -> float:
        """``finger_gap`` of a finger out of contact: its tip's sphere must keep the air too."""
        tip = self.fingers[i].tip(qi)
        c, s = math.cos(pose[2]), math.sin(pose[2])
        x, z = to_object(float(tip[0]), float(tip[1]), float(pose[0]), float(pose[1]), c, s)
        air = point_box_distance(x, z, self.shape.half_x, self.shape.half_z) - self.tip_radius
        return min(self.finger_gap(i, qi, pose), air)

    def finger_gaps(self, i: int, Q: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """``finger_gap`` for many joint angles ``Q`` (n, 2) of finger ``i`` at once."""
        return self.joint_gaps(i, Q[:, 0], Q[:, 1], pose)

    def elbow_tip(self, i: int, q1: np.ndarray, q2: np.ndarray) -> tuple[np.ndarray, ...]:
        """Elbow and tip centre ``(ex, ez, tx, tz)`` of finger ``i`` for arrays of joint
        angles that broadcast together."""
        f = self.fingers[i]
        ex, ez = f.base_x + f.l1 * np.cos(q1), f.base_z + f.l1 * np.sin(q1)
        q12 = q1 + q2
        return ex, ez, ex + f.l2 * np.cos(q12), ez + f.l2 * np.sin(q12)

    def joint_gaps(self, i: int, q1: np.ndarray, q2: np.ndarray, pose: np.ndarray
                   ) -> np.ndarray:
        """``finger_gap`` for arrays of first and second joint angles that broadcast
        together. A grid (``q1`` a column, ``q2`` a row) checks each proximal link once."""
        f = self.fingers[i]
        ex, ez, tx, tz = self.elbow_tip(i, q1, q2)
        lo, hi = self.palm_x
        below = ((lo <= ex) & (ex <= hi) & (ez < f.base_z)) | \
                ((lo <= tx) & (tx <= hi) & (tz < f.base_z))
        px, pz, c, s = float(pose[0]), float(pose[1]), math.cos(pose[2]), math.sin(pose[2])
        bx, bz = to_object(f.base_x, f.base_z, px, pz, c, s)
        exo, ezo = to_object(ex, ez, px, pz, c, s)
        inner = (f.l2 - TIP_OVERLAP * self.tip_radius) / f.l2
        txo, tzo = to_object(ex + inner * (tx - ex), ez + inner * (tz - ez), px, pz, c, s)
        hx, hz = self.shape.half_x, self.shape.half_z
        gap = np.minimum(segment_box_distances(np.full_like(exo, bx), np.full_like(ezo, bz),
                                               exo, ezo, hx, hz),
                         segment_box_distances(exo, ezo, txo, tzo, hx, hz)) - self.link_radius
        return np.where(below, -np.inf, gap)

    def clear(self, q: np.ndarray, pose: np.ndarray, fingers=(0, 1, 2)) -> bool:
        """The object above the palm and the links of ``fingers`` clear of it, by the
        clearance margin."""
        return self.palm_gap(pose) >= self.clearance and all(
            self.finger_gap(i, q[2 * i:2 * i + 2], pose) >= self.clearance for i in fingers)

    def tips(self, q: np.ndarray) -> np.ndarray:
        """Fingertip centres (3, 2) from joint angles (6,)."""
        return np.array([f.tip(q[2 * i:2 * i + 2]) for i, f in enumerate(self.fingers)])

    def surface_gap(self, finger: int, face, pose: np.ndarray, q: np.ndarray
                    ) -> tuple[float, float]:
        """How far finger's tip surface is off ``face`` (m, negative when pressed in) and its
        coordinate along the face (m), from the joints and the given object pose."""
        R = rotation(pose[2])
        tip_O = R.T @ (self.fingers[finger].tip(q[2 * finger:2 * finger + 2]) - pose[:2])
        surface, inward = self.shape.local_contact(face, 0.0)
        gap = float((surface - tip_O) @ inward) - self.tip_radius
        return gap, self.shape.coord_of(face, tip_O)

    def measured(self, contacts: Contacts, pose: np.ndarray, q: np.ndarray) -> Contacts:
        """``contacts`` with each coordinate taken from the measured tip and the given pose."""
        R = rotation(pose[2])
        tips_O = (self.tips(q) - pose[:2]) @ R  # rows: R^T (tip - p)
        coords = tuple(self.shape.coord_of(f, t) for f, t in zip(contacts.posture.faces, tips_O,
                                                                 strict=True))
        return Contacts(contacts.posture, coords, contacts.active)


def elongated(model: HandModel) -> bool:
    """True for a pole-like object: its grasps use the two long faces only."""
    return model.shape.length_m > 2 * model.shape.width_m
