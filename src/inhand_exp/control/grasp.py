"""Grasp postures and contact configurations on a box-shaped object, and the 2D grasp matrix.

Object frame ``O``: origin at the centre of mass, ``O_z`` along the long axis, ``O_x`` across it,
rotated by ``theta`` from the hand frame: at ``theta = 0`` a pole stands upright between the
fingers, and ``theta`` is its tilt from vertical (counter-clockwise, to the left). A box has four
faces: LEFT and RIGHT are a pole's long sides, TOP and BOTTOM its ends. A finger's contact is
given by its face and its coordinate along that face (m, measured from the face centre, positive
towards ``+O_x`` on the top/bottom faces and ``+O_z`` on the left/right faces). These types live
in ``control`` because the controllers need them; ``task`` builds on them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np


class Face(IntEnum):
    """A side of the box: TOP is +O_z, BOTTOM -O_z, RIGHT +O_x, LEFT -O_x (a pole's long sides
    are LEFT and RIGHT)."""

    TOP = 0
    BOTTOM = 1
    RIGHT = 2
    LEFT = 3


# Per face: outward normal and tangent (the direction of increasing contact coordinate), in O.
_OUTWARD = {Face.TOP: (0.0, 1.0), Face.BOTTOM: (0.0, -1.0),
            Face.RIGHT: (1.0, 0.0), Face.LEFT: (-1.0, 0.0)}
_ALONG = {Face.TOP: (1.0, 0.0), Face.BOTTOM: (1.0, 0.0),
          Face.RIGHT: (0.0, 1.0), Face.LEFT: (0.0, 1.0)}


@dataclass(frozen=True)
class Posture:
    """Which face each finger is on, finger 0 (left base) to finger 2 (right base)."""

    faces: tuple[Face, Face, Face]

    def __str__(self) -> str:
        return "/".join(f.name.lower() for f in self.faces)


@dataclass(frozen=True)
class Contacts:
    """A contact configuration: the posture and each finger's coordinate along its face (m).

    ``active`` marks the fingers in contact (a flip or a release lifts one).
    """

    posture: Posture
    coords: tuple[float, float, float]
    active: tuple[bool, bool, bool] = (True, True, True)

    def moved(self, finger: int, coord: float | None = None, face: Face | None = None,
              active: bool | None = None) -> Contacts:
        """A copy with one finger's coordinate, face or activity changed."""
        coords, faces, act = list(self.coords), list(self.posture.faces), list(self.active)
        if coord is not None:
            coords[finger] = coord
        if face is not None:
            faces[finger] = face
        if active is not None:
            act[finger] = active
        return Contacts(Posture(tuple(faces)), tuple(coords), tuple(act))


@dataclass(frozen=True)
class BoxShape:
    """The controller's model of the object: a uniform box (m, kg), ``length_m`` along ``O_z``
    (the long axis) and ``width_m`` along ``O_x``."""

    length_m: float
    width_m: float
    mass_kg: float

    @property
    def inertia(self) -> float:
        return self.mass_kg * (self.length_m**2 + self.width_m**2) / 12

    @property
    def half_x(self) -> float:
        """Half the extent along ``O_x`` (across the long axis)."""
        return self.width_m / 2

    @property
    def half_z(self) -> float:
        """Half the extent along ``O_z`` (the long axis)."""
        return self.length_m / 2

    def half_extent(self, face: Face) -> float:
        """Half the length of ``face`` (the range of its contact coordinate)."""
        return self.half_x if face in (Face.TOP, Face.BOTTOM) else self.half_z

    def depth(self, face: Face) -> float:
        """Distance from the centre of mass to ``face``'s plane."""
        return self.half_z if face in (Face.TOP, Face.BOTTOM) else self.half_x

    def local_contact(self, face: Face, coord: float) -> tuple[np.ndarray, np.ndarray]:
        """Contact point ``O_p`` on the surface and the inward unit normal ``O_n``, in O."""
        out, along = _OUTWARD[face], _ALONG[face]
        depth = self.depth(face)
        p = np.array([out[0] * depth + along[0] * coord, out[1] * depth + along[1] * coord])
        return p, -np.array(out)

    def coord_of(self, face: Face, point_O: np.ndarray) -> float:
        """Contact coordinate along ``face`` of a point given in the object frame (m)."""
        return float(point_O @ np.array(_ALONG[face]))


def face_axes(face: Face) -> tuple[np.ndarray, np.ndarray]:
    """Inward unit normal and the direction of increasing contact coordinate of ``face``, in O."""
    return -np.array(_OUTWARD[face]), np.array(_ALONG[face])


def rotation(theta: float) -> np.ndarray:
    """``W_R_O`` for an object turned by ``theta`` (rad) counter-clockwise."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


def face_shifted(pose: np.ndarray, inward_O: np.ndarray, gap: float) -> np.ndarray:
    """The pose that puts the nominal object's face of inward normal ``inward_O`` ``gap``
    further out (negative: further in), where a fingertip found it: the nominal shape checked
    at this pose stands for the real object on that side (a thinner or thicker one, or one
    seen with an error)."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    nx, nz = -gap * float(inward_O[0]), -gap * float(inward_O[1])
    return np.array([pose[0] + c * nx - s * nz, pose[1] + s * nx + c * nz, pose[2]])


def cross2(a: np.ndarray, b: np.ndarray) -> float:
    """z-component of the planar cross product: torque of force ``b`` at lever ``a``."""
    return float(a[0] * b[1] - a[1] * b[0])


def contact_frames(shape: BoxShape, contacts: Contacts, pose: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """World contact points (3, 2) and inward normals (3, 2) for every finger (active or not)."""
    R = rotation(pose[2])
    pts, nrm = np.empty((3, 2)), np.empty((3, 2))
    for i, (face, coord) in enumerate(zip(contacts.posture.faces, contacts.coords, strict=True)):
        p, n = shape.local_contact(face, coord)
        pts[i] = pose[:2] + R @ p
        nrm[i] = R @ n
    return pts, nrm


def grasp_matrix(levers: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """``G`` (3, 2k) for hard-finger point contacts: ``G @ lam`` is the wrench on the object.

    ``levers`` (k, 2) are contact points relative to the object's COM, ``normals`` (k, 2) the
    inward unit normals; ``lam`` stacks ``(f_n, f_t)`` per contact, ``f_t`` along the normal
    turned 90 deg counter-clockwise. The wrench is ``(F_x, F_z, tau)`` in the same frame.
    """
    k = len(levers)
    G = np.empty((3, 2 * k))
    for i in range(k):
        n = normals[i]
        t = np.array([-n[1], n[0]])
        G[:2, 2 * i], G[:2, 2 * i + 1] = n, t
        G[2, 2 * i], G[2, 2 * i + 1] = cross2(levers[i], n), cross2(levers[i], t)
    return G
