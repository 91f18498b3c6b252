"""How far the finger links stay from the object: the geometry behind "no link cuts the object".

The controllers' model of the hand is three two-link arms whose links are capsules of radius
``link_radius`` round the segments base-elbow and elbow-tip, on a palm plane at the bases. A
grasp or a path is acceptable when every link keeps ``margin`` metres of air to the object
(``link_gap``) and the object keeps the same above the palm (``palm_gap``). Plain floats: this
runs for every candidate grasp the samplers and the feasibility filter look at.
"""

from __future__ import annotations

import math

import numpy as np


def point_box_distance(x: float, z: float, hx: float, hz: float) -> float:
    """Distance (m) from point (x, z) to the box ``|x| <= hx, |z| <= hz``; 0 inside it."""
    ex, ez = max(abs(x) - hx, 0.0), max(abs(z) - hz, 0.0)
    return math.hypot(ex, ez)


def segment_box_distance(ax: float, az: float, bx: float, bz: float, hx: float, hz: float
                         ) -> float:
    """Distance (m) from segment a-b to the box ``|x| <= hx, |z| <= hz``; 0 when they meet.

    They meet when no separating axis parts them: neither x nor z (the bounding boxes
    overlap) nor the segment's normal. Between a segment and a convex polygon that do not meet,
    the distance is reached at an end of the segment or at a corner of the polygon: a corner's
    distance to the segment's line where its foot falls inside the segment (a foot outside is
    farther than the nearer end is from the box).
    """
    dx, dz = bx - ax, bz - az
    if (max(ax, bx) >= -hx and min(ax, bx) <= hx and max(az, bz) >= -hz and min(az, bz) <= hz
            and abs(dz * ax - dx * az) <= abs(dz) * hx + abs(dx) * hz):
        return 0.0
    best = min(point_box_distance(ax, az, hx, hz), point_box_distance(bx, bz, hx, hz))
    n = dx * dx + dz * dz
    for cx in (-hx, hx):
        ex = cx - ax
        for cz in (-hz, hz):
            ez = cz - az
            foot = ex * dx + ez * dz
            if 0.0 < foot < n:
                best = min(best, abs(dx * ez - dz * ex) / math.sqrt(n))
    return best


def segment_box_distances(ax: np.ndarray, az: np.ndarray, bx: np.ndarray, bz: np.ndarray,
                          hx: float, hz: float) -> np.ndarray:
    """``segment_box_distance`` over arrays of segments at once (the same answers, to rounding);
    the four arrays may broadcast.

    A segment meets the box when no separating axis parts them: neither x nor z (the bounding
    boxes overlap) nor the segment's normal. Otherwise the distance is an end's to the box or
    a corner's to the segment's line, where the corner's foot falls inside the segment (a foot
    outside is farther than the nearer end is from the box).
    """
    dx, dz = bx - ax, bz - az
    meets = ((np.maximum(ax, bx) >= -hx) & (np.minimum(ax, bx) <= hx)
             & (np.maximum(az, bz) >= -hz) & (np.minimum(az, bz) <= hz)
             & (np.abs(dz * ax - dx * az) <= np.abs(dz) * hx + np.abs(dx) * hz))
    best = np.minimum(np.hypot(np.maximum(np.abs(ax) - hx, 0.0), np.maximum(np.abs(az) - hz, 0.0)),
                      np.hypot(np.maximum(np.abs(bx) - hx, 0.0), np.maximum(np.abs(bz) - hz, 0.0)))
    n = dx * dx + dz * dz
    cross = np.full(n.shape, np.inf)  # |d x (corner - a)|, the line's distance times |d|
    for cx in (-hx, hx):
        ex = cx - ax
        for cz in (-hz, hz):
            ez = cz - az
            foot = ex * dx + ez * dz
            cross = np.where((foot > 0.0) & (foot < n),
                             np.minimum(cross, np.abs(dx * ez - dz * ex)), cross)
    with np.errstate(divide="ignore", invalid="ignore"):  # n = 0: no foot inside, inf / 0
        best = np.minimum(best, cross / np.sqrt(n))
    return np.where(meets, 0.0, best)


def to_object(x: float, z: float, px: float, pz: float, c: float, s: float
              ) -> tuple[float, float]:
    """A hand-frame point in the frame of an object at ``(px, pz)`` turned by (cos, sin)."""
    rx, rz = x - px, z - pz
    return c * rx + s * rz, -s * rx + c * rz


def lowest_corner(pose, half_x: float, half_z: float) -> float:
    """z of the lowest point of a box of half extents ``half_x, half_z`` at ``pose``."""
    c, s = abs(math.cos(pose[2])), abs(math.sin(pose[2]))
    return float(pose[1]) - (half_x * s + half_z * c)
