"""The ``/scene`` topic: the hand, the object and the goal as Foxglove ``SceneUpdate`` messages.

Foxglove's 3D panel draws any JSON channel whose schema is named ``foxglove.SceneUpdate``, so a
run log opens there with the hand moving the object. The plane of the hand is the world's x-z
plane (frame ``world``, z up, y out of the plane), as in PyBullet; the object turns about -y, so
an angle theta is the quaternion (0, -sin(theta/2), 0, cos(theta/2)).

Each message is one snapshot of ``/sim/state`` with the whole scene in it (the entities replace
their namesakes): the palm plate, each finger's two links (a line strip as thick as the links)
and its tip (a sphere), the object (a box of the simulated, perturbed size), the goal pose (a
translucent box), one arrow per fingertip contact along its normal force, and a caption.

``SceneReplay`` lays the first ``episodes`` evaluation episodes out one after another on a
replay timeline that starts when the evaluation starts, so that scrubbing Foxglove's timeline
plays them in turn; their snapshots are held until the episode ends (its goal and outcome are
then known).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

FRAME = "world"
ARROW_M_PER_N = 0.01  # drawn length of a contact arrow per newton of normal force (m/N)
GAP_S = 1.0  # replay time between two episodes (s)
LINE_STRIP = 0  # foxglove.LineType
DELETE_ALL = 1  # foxglove.SceneEntityDeletionType

# Colours (r, g, b, a).
PALM, LINK, TIP = (0.55, 0.55, 0.55, 1.0), (0.27, 0.51, 0.71, 1.0), (0.0, 0.0, 0.5, 1.0)
BODY, GOAL, FORCE = (0.82, 0.71, 0.55, 1.0), (0.1, 0.7, 0.1, 0.3), (0.9, 0.1, 0.1, 1.0)


# --- the schema: the parts of foxglove.SceneUpdate this topic writes ------------------------

def _number(description: str) -> dict[str, Any]:
    return {"type": "number", "description": description}


def _obj(title: str, description: str, properties: dict[str, Any]) -> dict[str, Any]:
    return {"title": title, "type": "object", "description": description,
            "properties": properties, "required": list(properties)}


def _xyz(title: str, description: str) -> dict[str, Any]:
    return _obj(title, description, {k: _number(f"{k} (m)") for k in "xyz"})


def _time(description: str) -> dict[str, Any]:
    return {"type": "object", "title": "time", "description": description, "properties": {
        "sec": {"type": "integer", "minimum": 0, "description": "Whole seconds (s)."},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999,
                 "description": "Nanoseconds within the second."}}}


def _color(description: str) -> dict[str, Any]:
    return _obj("foxglove.Color", description, {c: _number(f"{name}, 0 to 1") for c, name in
                                                zip("rgba", ("red", "green", "blue", "alpha"),
                                                    strict=True)})


def _pose(description: str) -> dict[str, Any]:
    quat = _obj("foxglove.Quaternion", "Orientation.", {k: _number(f"{k} value") for k in "xyzw"})
    return _obj("foxglove.Pose", description,
                {"position": _xyz("foxglove.Vector3", "Position (m)."), "orientation": quat})


def _array(description: str, items: dict[str, Any]) -> dict[str, Any]:
    return {"type": "array", "description": description, "items": items}


_POINT = _xyz("foxglove.Point3", "A point (m).")
_ENTITY = {
    "title": "foxglove.SceneEntity", "type": "object",
    "description": "A visual element of the scene, made of primitives in one frame.",
    "properties": {
        "timestamp": _time("Time of the entity."),
        "frame_id": {"type": "string", "description": "Frame of reference."},
        "id": {"type": "string", "description": "Identifier; replaces the prior entity with "
               "this id on the topic."},
        "lifetime": {**_time("How long the entity stays; zero: until replaced."),
                     "title": "duration"},
        "frame_locked": {"type": "boolean", "description": "Follow frame_id as it moves."},
        "metadata": _array("Key-value pairs about the entity.", _obj(
            "foxglove.KeyValuePair", "A key and its value.",
            {"key": {"type": "string", "description": "Key."},
             "value": {"type": "string", "description": "Value."}})),
        "arrows": _array("Arrows.", _obj("foxglove.ArrowPrimitive", "An arrow along its +x.", {
            "pose": _pose("Tail position and orientation."),
            "shaft_length": _number("Length of the shaft (m)."),
            "shaft_diameter": _number("Diameter of the shaft (m)."),
            "head_length": _number("Length of the head (m)."),
            "head_diameter": _number("Diameter of the head (m)."),
            "color": _color("Colour.")})),
        "cubes": _array("Boxes.", _obj("foxglove.CubePrimitive", "A box.", {
            "pose": _pose("Centre and orientation."),
            "size": _xyz("foxglove.Vector3", "Extent along each local axis (m)."),
            "color": _color("Colour.")})),
        "spheres": _array("Spheres.", _obj("foxglove.SpherePrimitive", "A sphere.", {
            "pose": _pose("Centre and orientation."),
            "size": _xyz("foxglove.Vector3", "Diameter along each local axis (m)."),
            "color": _color("Colour.")})),
        "lines": _array("Lines.", {
            **_obj("foxglove.LinePrimitive", "Connected line segments.", {
                "type": {"type": "integer", "minimum": 0, "maximum": 2,
                         "description": "0 line strip, 1 line loop, 2 line list."},
                "pose": _pose("Origin of the points."),
                "thickness": _number("Line thickness (m)."),
                "scale_invariant": {"type": "boolean",
                                    "description": "Thickness in pixels rather than metres."},
                "points": _array("Vertices.", _POINT),
                "color": _color("Colour of the whole line.")}),
            "required": ["type", "pose", "thickness", "scale_invariant", "points", "color"]}),
        "texts": _array("Captions.", _obj("foxglove.TextPrimitive", "A text label.", {
            "pose": _pose("Where the text is."),
            "billboard": {"type": "boolean", "description": "Always face the camera."},
            "font_size": _number("Font size (pixels when scale_invariant)."),
            "scale_invariant": {"type": "boolean", "description": "Font size in pixels."},
            "color": _color("Colour."),
            "text": {"type": "string", "description": "The text."}})),
    },
    "required": ["timestamp", "frame_id", "id", "lifetime", "frame_locked"],
}
_DELETION = _obj("foxglove.SceneEntityDeletion", "Removes entities published earlier.", {
    "timestamp": _time("Entities older than this are deleted."),
    "type": {"type": "integer", "minimum": 0, "maximum": 1,
             "description": "0 the entity named by id, 1 every entity on the topic."},
    "id": {"type": "string", "description": "Id to delete when type is 0."},
})


def scene_update_schema(draft: str, note: str) -> dict[str, Any]:
    """The JSON Schema of ``/scene``: Foxglove's ``foxglove.SceneUpdate``, the fields we use."""
    return {"$schema": draft, "title": "foxglove.SceneUpdate",
            "description": "An update to the entities of the 3D scene: the hand, the object and "
                           f"the goal at one instant of an evaluation episode (Foxglove). {note}",
            "type": "object",
            "properties": {"deletions": _array("Entities to delete first.", _DELETION),
                           "entities": _array("Entities to add or replace.", _ENTITY)},
            "required": ["deletions", "entities"]}


# --- the messages ---------------------------------------------------------------------------

def finger_points(q, base_x: float, base_z: float, l1: float, l2: float) -> np.ndarray:
    """Base, elbow and tip centre (3, 2) of a planar two-link finger at joint angles ``q``."""
    q1, q12 = q[0], q[0] + q[1]
    elbow = (base_x + l1 * math.cos(q1), base_z + l1 * math.sin(q1))
    tip = (elbow[0] + l2 * math.cos(q12), elbow[1] + l2 * math.sin(q12))
    return np.array([(base_x, base_z), elbow, tip])


@dataclass(frozen=True)
class SceneGeometry:
    """What the scene draws, from a run's config (the simulated object, perturbation included)."""

    finger_base_x: tuple[float, ...]
    base_z: float
    link_lengths: tuple[float, float]
    link_radius: float
    tip_radius: float
    palm_thickness: float
    palm_overhang: float
    object_size: tuple[float, float, float]  # width (x), depth (y), length (z) at theta = 0

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any]) -> SceneGeometry:
        """From a run's config (``hand``, ``object`` and ``perturb`` nodes, dict or DictConfig)."""
        hand, obj, p = cfg["hand"], cfg["object"], cfg.get("perturb") or {}
        return cls(tuple(hand["finger_base_x_m"]), float(hand.get("base_z_m", 0.0)),
                   tuple(hand["link_lengths_m"]), float(hand.get("link_radius_m", 0.008)),
                   float(hand["tip_radius_m"]), float(hand.get("palm_thickness_m", 0.02)),
                   float(hand.get("palm_overhang_m", 0.06)),
                   (obj["width_m"] * p.get("width_scale", 1.0), obj.get("depth_m", 0.05),
                    obj["length_m"] * p.get("length_scale", 1.0)))


def stamp(ns: int) -> dict[str, int]:
    """A Foxglove time from nanoseconds."""
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def planar_pose(x: float, z: float, theta: float = 0.0) -> dict[str, Any]:
    """A Foxglove pose in the hand's plane: at (x, 0, z), turned by ``theta`` about -y."""
    return {"position": {"x": float(x), "y": 0.0, "z": float(z)},
            "orientation": {"x": 0.0, "y": -math.sin(theta / 2), "z": 0.0,
                            "w": math.cos(theta / 2)}}


def _rgba(c) -> dict[str, float]:
    return dict(zip("rgba", (float(v) for v in c), strict=True))


def _entity(name: str, time_ns: int, **primitives) -> dict[str, Any]:
    return {"timestamp": stamp(time_ns), "frame_id": FRAME, "id": name,
            "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": False, "metadata": [],
            **primitives}


def _solid(pose: dict, size, color) -> dict[str, Any]:
    return {"pose": pose, "size": dict(zip("xyz", (float(s) for s in size), strict=True)),
            "color": _rgba(color)}


def scene_update(state: Mapping[str, Any], geometry: SceneGeometry, time_ns: int,
                 goal=None, caption: str = "", clear: bool = False) -> dict[str, Any]:
    """One ``foxglove.SceneUpdate`` from one ``/sim/state`` message; ``goal`` (x, z, theta) or
    None; ``clear`` deletes every entity first (a new episode)."""
    g = geometry
    (l1, l2), q = g.link_lengths, state["joint_q"]
    xs = g.finger_base_x
    palm_w = xs[-1] - xs[0] + 2 * g.palm_overhang
    palm = _solid(planar_pose((xs[0] + xs[-1]) / 2, g.base_z - g.palm_thickness / 2),
                (palm_w, 4 * g.object_size[1], g.palm_thickness), PALM)
    lines, tips = [], []
    for i, bx in enumerate(xs):
        pts = finger_points(q[2 * i:2 * i + 2], bx, g.base_z, l1, l2)
        lines.append({"type": LINE_STRIP, "pose": planar_pose(0.0, 0.0),
                      "thickness": 2 * g.link_radius, "scale_invariant": False,
                      "points": [{"x": float(x), "y": 0.0, "z": float(z)} for x, z in pts],
                      "color": _rgba(LINK)})
        tips.append(_solid(planar_pose(*pts[2]), [2 * g.tip_radius] * 3, TIP))
    x, z, th = state["object_pose"]
    arrows = []
    for c in state.get("contacts", []):
        fn = c.get("normal_force_n")
        if fn is None or not math.isfinite(fn):
            continue
        d = np.array([x, z]) - np.array(c["position"])  # drawn along the line to the centre
        length = max(fn, 0.0) * ARROW_M_PER_N
        arrows.append({"pose": planar_pose(*c["position"], math.atan2(d[1], d[0])),
                       "shaft_length": 0.7 * length, "shaft_diameter": 0.004,
                       "head_length": 0.3 * length, "head_diameter": 0.01,
                       "color": _rgba(FORCE)})
    entities = [
        _entity("palm", time_ns, cubes=[palm]),
        _entity("fingers", time_ns, lines=lines, spheres=tips),
        _entity("object", time_ns, cubes=[_solid(planar_pose(x, z, th), g.object_size, BODY)]),
        _entity("contacts", time_ns, arrows=arrows),
    ]
    if goal is not None:
        entities.append(_entity("goal", time_ns, cubes=[
            _solid(planar_pose(*goal), g.object_size, GOAL)]))
    if caption:
        top = g.base_z + l1 + l2 + 0.1
        entities.append(_entity("caption", time_ns, texts=[{
            "pose": planar_pose(0.0, top), "billboard": True, "font_size": 14.0,
            "scale_invariant": True, "color": _rgba((0.0, 0.0, 0.0, 1.0)), "text": caption}]))
    deletions = [{"timestamp": stamp(time_ns), "type": DELETE_ALL, "id": ""}] if clear else []
    return {"deletions": deletions, "entities": entities}


class SceneReplay:
    """Writes ``/scene`` for the first ``episodes`` episodes of an evaluation, one after another.

    Feed it every ``/sim/state`` message (``on_state``) and every ``/eval/episode`` record
    (``on_episode``); ``write(topic, message, log_time_ns)`` is the run log's. An episode's
    snapshots are held until it ends, then written at ``start_ns`` + the replay time so far.
    """

    def __init__(self, write, geometry: SceneGeometry, episodes: int, start_ns: int):
        self.write, self.geometry, self.episodes = write, geometry, episodes
        self.cursor_ns = int(start_ns)
        self.held: dict[int, list[Mapping[str, Any]]] = {}

    def on_state(self, msg: Mapping[str, Any]) -> None:
        if msg.get("episode", 0) < self.episodes:
            self.held.setdefault(msg.get("episode", 0), []).append(msg)

    def on_episode(self, rec: Mapping[str, Any]) -> None:
        states = sorted(self.held.pop(rec["episode"], []), key=lambda m: m["sim_time_s"])
        if not states:
            return
        outcome = "success" if rec["success"] else "dropped" if rec["dropped"] else "timeout"
        for k, s in enumerate(states):
            t_ns = self.cursor_ns + round(s["sim_time_s"] * 1e9)
            caption = f"episode {rec['episode']} ({rec.get('group', '')})  " \
                      f"t = {s['sim_time_s']:.2f} s"
            if k == len(states) - 1:
                caption += f"  {outcome}"
            self.write("/scene", scene_update(s, self.geometry, t_ns, rec.get("xg"), caption,
                                              clear=k == 0), t_ns)
        self.cursor_ns += round((states[-1]["sim_time_s"] + GAP_S) * 1e9)
