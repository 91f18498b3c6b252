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


def _clip(p: float, q: float, t0: float, t1: float) -> tuple[float, float] | None:
    """One Liang-Barsky step: the part of [t0, t1] where ``p t <= q``."""
    if p == 0.0:
        return (t0, t1) if q >= 0.0 else None
    r = q / p
    if p < 0.0:
        t0 = max(t0, r)
    else:
        t1 = min(t1, r)
    return (t0, t1) if t0 <= t1 else None


def segment_crosses_box(ax: float, az: float, bx: float, bz: float, hx: float, hz: float
                        ) -> bool:
    """True when segment a-b meets the box ``|x| <= hx, |z| <= hz``."""
    dx, dz = bx - ax, bz - az
    span: tuple[float, float] | None = (0.0, 1.0)
    for p, q in ((-dx, ax + hx), (dx, hx - ax), (-dz, az + hz), (dz, hz - az)):
        span = _clip(p, q, *span)
        if span is None:
            return False
    return True


def _point_box(x: float, z: float, hx: float, hz: float) -> float:
    ex, ez = max(abs(x) - hx, 0.0), max(abs(z) - hz, 0.0)
    return math.hypot(ex, ez)


def _point_segment(x: float, z: float, ax: float, az: float, bx: float, bz: float) -> float:
    dx, dz = bx - ax, bz - az
    n = dx * dx + dz * dz
    s = 0.0 if n == 0.0 else min(1.0, max(0.0, ((x - ax) * dx + (z - az) * dz) / n))
    return math.hypot(ax + s * dx - x, az + s * dz - z)


def segment_box_distance(ax: float, az: float, bx: float, bz: float, hx: float, hz: float
                         ) -> float:
    """Distance (m) from segment a-b to the box ``|x| <= hx, |z| <= hz``; 0 when they meet.

    Between a segment and a convex polygon that do not meet, the distance is reached at an end
    of the segment or at a corner of the polygon.
    """
    if segment_crosses_box(ax, az, bx, bz, hx, hz):
        return 0.0
    best = min(_point_box(ax, az, hx, hz), _point_box(bx, bz, hx, hz))
    for cx in (-hx, hx):
        for cz in (-hz, hz):
            best = min(best, _point_segment(cx, cz, ax, az, bx, bz))
    return best


def segment_box_distances(ax: np.ndarray, az: np.ndarray, bx: np.ndarray, bz: np.ndarray,
                          hx: float, hz: float) -> np.ndarray:
    """``segment_box_distance`` over arrays of segments at once (the same answers)."""
    dx, dz = bx - ax, bz - az
    t0, t1 = np.zeros(ax.shape), np.ones(ax.shape)
    meets = np.ones(ax.shape, dtype=bool)
    for p, q in ((-dx, ax + hx), (dx, hx - ax), (-dz, az + hz), (dz, hz - az)):
        flat = p == 0.0
        meets &= ~flat | (q >= 0.0)
        r = q / np.where(flat, 1.0, p)
        t0 = np.where(p < 0.0, np.maximum(t0, r), t0)
        t1 = np.where(p > 0.0, np.minimum(t1, r), t1)
    meets &= t0 <= t1
    best = np.minimum(np.hypot(np.maximum(np.abs(ax) - hx, 0.0), np.maximum(np.abs(az) - hz, 0.0)),
                      np.hypot(np.maximum(np.abs(bx) - hx, 0.0), np.maximum(np.abs(bz) - hz, 0.0)))
    n = dx * dx + dz * dz
    safe = np.where(n == 0.0, 1.0, n)
    for cx in (-hx, hx):
        for cz in (-hz, hz):
            s = np.where(n == 0.0, 0.0, np.clip(((cx - ax) * dx + (cz - az) * dz) / safe, 0.0, 1.0))
            best = np.minimum(best, np.hypot(ax + s * dx - cx, az + s * dz - cz))
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
