"""URDF text for one planar finger and for the planar object, from explicit geometry and inertia."""

from __future__ import annotations

import math

# Rotation taking a URDF cylinder/capsule axis (z) onto the link's x axis.
_ALONG_X = f"0 {math.pi / 2} 0"
# Every joint turns about -y, so positive angles are counter-clockwise in the x-z view.
_AXIS = "0 -1 0"


def _inertial(mass: float, com_x: float, iyy: float, ixx: float | None = None) -> str:
    ixx = iyy if ixx is None else ixx
    return (f'<inertial><origin xyz="{com_x} 0 0"/><mass value="{mass}"/>'
            f'<inertia ixx="{ixx}" ixy="0" ixz="0" iyy="{iyy}" iyz="0" izz="{iyy}"/></inertial>')


def _capsule(length: float, radius: float) -> str:
    return (f'<collision><origin xyz="{length / 2} 0 0" rpy="{_ALONG_X}"/>'
            f'<geometry><capsule radius="{radius}" length="{length}"/></geometry></collision>')


def finger_urdf(lengths: tuple[float, float], masses: tuple[float, float], link_radius: float,
                tip_mass: float, tip_radius: float, q_lower: tuple[float, float],
                q_upper: tuple[float, float], max_torque: float) -> str:
    """A fixed base, two revolute joints about -y and a spherical tip on a fixed joint.

    Link indices in PyBullet: 0 proximal, 1 distal, 2 tip. Link inertias are uniform rods
    (``m l^2 / 12`` about the COM), the tip a solid sphere, matching ``control.finger``.
    """
    (l1, l2), (m1, m2) = lengths, masses
    links = [
        f'<link name="base">{_inertial(0.0, 0.0, 0.0)}</link>',
        f'<link name="proximal">{_inertial(m1, l1 / 2, m1 * l1**2 / 12, 1e-6)}'
        f'{_capsule(l1, link_radius)}</link>',
        f'<link name="distal">{_inertial(m2, l2 / 2, m2 * l2**2 / 12, 1e-6)}'
        f'{_capsule(l2, link_radius)}</link>',
        f'<link name="tip">{_inertial(tip_mass, 0.0, 0.4 * tip_mass * tip_radius**2)}'
        f'<collision><geometry><sphere radius="{tip_radius}"/></geometry></collision></link>',
    ]
    joints = [
        _revolute("j1", "base", "proximal", 0.0, q_lower[0], q_upper[0], max_torque),
        _revolute("j2", "proximal", "distal", l1, q_lower[1], q_upper[1], max_torque),
        f'<joint name="tip" type="fixed"><parent link="distal"/><child link="tip"/>'
        f'<origin xyz="{l2} 0 0"/></joint>',
    ]
    return _robot("finger", links, joints)


def _revolute(name: str, parent: str, child: str, x: float, lo: float, hi: float,
              effort: float) -> str:
    return (f'<joint name="{name}" type="revolute"><parent link="{parent}"/>'
            f'<child link="{child}"/><origin xyz="{x} 0 0"/><axis xyz="{_AXIS}"/>'
            f'<limit lower="{lo}" upper="{hi}" effort="{effort}" velocity="1e6"/>'
            f'<dynamics damping="0" friction="0"/></joint>')


# Mass of the two massless-in-spirit slider links that constrain the object to the plane (kg).
SLIDER_MASS = 1e-5


def object_urdf(length: float, width: float, depth: float, mass: float) -> str:
    """A box on a world-fixed chain: prismatic x, prismatic z, revolute about -y.

    Link indices: 0 x slider, 1 z slider, 2 the body (a uniform box, long axis along z at zero
    angle: a pole stands upright). The sliders carry no collision shape and a negligible mass;
    the motors are left to the caller to disable.
    """
    tiny = _inertial(SLIDER_MASS, 0.0, 1e-9)
    iyy = mass * (length**2 + width**2) / 12
    body = (f'<link name="body">{_inertial(mass, 0.0, iyy, mass * (width**2 + depth**2) / 12)}'
            f'<collision><geometry><box size="{width} {depth} {length}"/></geometry>'
            f'</collision></link>')
    links = [f'<link name="world">{_inertial(0.0, 0.0, 0.0)}</link>',
             f'<link name="x">{tiny}</link>', f'<link name="z">{tiny}</link>', body]
    far = 10.0
    joints = [
        f'<joint name="px" type="prismatic"><parent link="world"/><child link="x"/>'
        f'<axis xyz="1 0 0"/><limit lower="{-far}" upper="{far}" effort="0" velocity="1000"/>'
        f'</joint>',
        f'<joint name="pz" type="prismatic"><parent link="x"/><child link="z"/>'
        f'<axis xyz="0 0 1"/><limit lower="{-far}" upper="{far}" effort="0" velocity="1000"/>'
        f'</joint>',
        f'<joint name="rot" type="continuous"><parent link="z"/><child link="body"/>'
        f'<axis xyz="{_AXIS}"/><dynamics damping="0" friction="0"/></joint>',
    ]
    return _robot("object", links, joints)


def palm_urdf(half_width: float, thickness: float, depth: float) -> str:
    """A static plate whose top face is the base's origin: the palm the fingers rise from."""
    return _robot("palm", [
        f'<link name="plate">{_inertial(0.0, 0.0, 0.0)}<collision>'
        f'<origin xyz="0 0 {-thickness / 2}"/><geometry><box size="{2 * half_width} {depth} '
        f'{thickness}"/></geometry></collision></link>'], [])


def _robot(name: str, links: list[str], joints: list[str]) -> str:
    return f'<?xml version="1.0"?><robot name="{name}">{"".join(links + joints)}</robot>'
