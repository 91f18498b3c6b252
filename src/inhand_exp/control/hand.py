"""The controller's model of the hand (three ``FingerModel``) and of the object, from config."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from inhand_exp.config import HandConfig, ObjectConfig
from inhand_exp.control.finger import FingerModel
from inhand_exp.control.grasp import BoxShape, Contacts, contact_frames, rotation

# Elbow branch per finger for inverse kinematics: the outer fingers bend inwards, which lets
# them reach round the ends of the object.
ELBOWS = (1, 1, -1)


class GeometryError(ValueError):
    """The hand cannot realise a grasp (a tip out of reach or outside its joint limits)."""


@dataclass(frozen=True)
class HandModel:
    """Three fingers, their tip radius and the nominal object, as the controllers know them."""

    fingers: tuple[FingerModel, FingerModel, FingerModel]
    tip_radius: float
    shape: BoxShape
    mu: float  # friction coefficient of fingertip on object, as combined by the simulator

    @classmethod
    def from_config(cls, hand: HandConfig, obj: ObjectConfig, gravity: float) -> HandModel:
        fingers = tuple(
            FingerModel.build(x, hand.base_z_m, tuple(hand.link_lengths_m),
                              tuple(hand.link_masses_kg), hand.tip_mass_kg, hand.tip_radius_m,
                              tuple(hand.joint_lower_rad), tuple(hand.joint_upper_rad), gravity)
            for x in hand.finger_base_x_m)
        shape = BoxShape(obj.length_m, obj.width_m, obj.mass_kg)
        model = cls(fingers, hand.tip_radius_m, shape, hand.friction * obj.friction)
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

    def tip_targets(self, contacts: Contacts, pose: np.ndarray) -> np.ndarray:
        """Fingertip centres (3, 2) touching the object at ``contacts`` when it is at ``pose``."""
        pts, nrm = contact_frames(self.shape, contacts, pose)
        return pts - self.tip_radius * nrm

    def grasp_q(self, contacts: Contacts, pose: np.ndarray, press: float = 0.0) -> np.ndarray:
        """Joint angles (6,) placing every tip on its contact, ``press`` metres into the surface.

        Raises ``GeometryError`` naming the finger when a contact is out of reach or limits.
        """
        pts, nrm = contact_frames(self.shape, contacts, pose)
        q = np.empty(6)
        for i, finger in enumerate(self.fingers):
            target = pts[i] - (self.tip_radius - press) * nrm[i]
            qi = finger.ik(target, ELBOWS[i])
            if qi is None:
                qi = finger.ik(target, -ELBOWS[i])
            if qi is None:
                raise GeometryError(f"finger {i} cannot reach its contact at "
                                    f"({target[0]:.3f}, {target[1]:.3f}) m")
            q[2 * i:2 * i + 2] = qi
        return q

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
