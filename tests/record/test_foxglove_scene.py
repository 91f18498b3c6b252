"""/scene: Foxglove SceneUpdate messages that match Foxglove's own definition and the physics."""

from __future__ import annotations

import copy
import math

import jsonschema
import numpy as np
import pytest
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf import json_format

from inhand_exp.control.finger import FingerModel
from inhand_exp.control.grasp import rotation
from inhand_exp.record import TOPIC_SCHEMAS
from inhand_exp.record.scene import SceneGeometry, SceneReplay, scene_update

CFG = {"hand": {"finger_base_x_m": [-0.12, 0.0, 0.12], "base_z_m": 0.0,
                "link_lengths_m": [0.16, 0.16], "link_radius_m": 0.008, "tip_radius_m": 0.012,
                "palm_thickness_m": 0.02, "palm_overhang_m": 0.06},
       "object": {"width_m": 0.02, "depth_m": 0.05, "length_m": 0.5},
       "perturb": {"width_scale": 1.5, "length_scale": 0.8}}
STATE = {"episode": 0, "sim_time_s": 0.5, "object_pose": [0.01, 0.3, 0.7],
         "joint_q": [1.2, 0.5, 1.5, 0.2, 1.9, -0.5],
         "contacts": [{"finger": 0, "position": [0.0, 0.3], "normal_force_n": 2.0,
                       "tangential_force_n": 0.1},
                      {"finger": 2, "position": [0.02, 0.31], "normal_force_n": None}]}
GEOMETRY = SceneGeometry.from_config(CFG)


def message(**kw):
    return scene_update(STATE, GEOMETRY, 1_700_000_000_250_000_000, goal=[0.0, 0.25, -0.3],
                        caption="episode 0", **kw)


def entity(msg, name):
    return next(e for e in msg["entities"] if e["id"] == name)


def _protobuf_json(value):
    """Foxglove's JSON form to protobuf's JSON mapping: times are {sec, nsec} in the first and
    RFC 3339 strings (durations "1.5s") in the second; everything else is the same."""
    if isinstance(value, list):
        return [_protobuf_json(v) for v in value]
    if not isinstance(value, dict):
        return value
    out = {}
    for key, v in value.items():
        if key == "timestamp":
            t = np.datetime64(v["sec"], "s") + np.timedelta64(v["nsec"], "ns")
            out[key] = f"{np.datetime_as_string(t, unit='ns')}Z"
        elif key == "lifetime":
            out[key] = f"{v['sec'] + v['nsec'] / 1e9}s"
        else:
            out[key] = _protobuf_json(v)
    return out


def test_messages_parse_into_foxglove_scene_update_and_validate_against_the_topic_schema():
    for clear in (False, True):
        msg = message(clear=clear)
        jsonschema.Draft202012Validator(TOPIC_SCHEMAS["/scene"]).validate(msg)
        # Foxglove's own definition (foxglove-schemas-protobuf): unknown fields or wrong types
        # raise here.
        parsed = json_format.ParseDict(_protobuf_json(msg), SceneUpdate())
        assert len(parsed.entities) == 6 and len(parsed.deletions) == int(clear)
    assert TOPIC_SCHEMAS["/scene"]["title"] == "foxglove.SceneUpdate"  # what Foxglove keys on


def test_a_field_foxglove_does_not_have_is_caught_by_both_checks():
    msg = message()
    msg["entities"][0]["cubes"][0]["colour"] = msg["entities"][0]["cubes"][0].pop("color")
    with pytest.raises(json_format.ParseError, match="colour"):
        json_format.ParseDict(_protobuf_json(msg), SceneUpdate())
    with pytest.raises(jsonschema.ValidationError, match="color"):
        jsonschema.Draft202012Validator(TOPIC_SCHEMAS["/scene"]).validate(msg)


def _rotate(q, v):
    """Rotate 3-vector ``v`` by the unit quaternion ``q`` (a dict with x, y, z, w)."""
    u = np.array([q["x"], q["y"], q["z"]])
    v = np.asarray(v, dtype=float)
    return v + 2 * q["w"] * np.cross(u, v) + 2 * np.cross(u, np.cross(u, v))


def test_the_object_box_is_the_simulated_pose_and_size():
    box = entity(message(), "object")["cubes"][0]
    x, z, th = STATE["object_pose"]
    assert box["pose"]["position"] == pytest.approx({"x": x, "y": 0.0, "z": z})
    axis = _rotate(box["pose"]["orientation"], [0, 0, 1])  # the long axis
    assert axis[[0, 2]] == pytest.approx(rotation(th) @ [0.0, 1.0])  # the controllers' frame
    assert axis[1] == pytest.approx(0.0)
    assert box["size"] == pytest.approx({"x": 0.03, "y": 0.05, "z": 0.4})  # perturbed


def test_fingertips_and_links_follow_the_controllers_forward_kinematics():
    fingers = entity(message(), "fingers")
    q = np.array(STATE["joint_q"])
    for i, bx in enumerate(CFG["hand"]["finger_base_x_m"]):
        model = FingerModel.build(bx, 0.0, (0.16, 0.16), (0.05, 0.05), 0.01, 0.012,
                                  (-0.5, -2.8), (3.6, 2.8))
        tip = model.tip(q[2 * i:2 * i + 2])
        sphere = fingers["spheres"][i]["pose"]["position"]
        assert [sphere["x"], sphere["z"]] == pytest.approx(tip)
        points = fingers["lines"][i]["points"]
        assert [points[0]["x"], points[0]["z"]] == pytest.approx([bx, 0.0])
        assert [points[-1]["x"], points[-1]["z"]] == pytest.approx(tip)
        assert fingers["lines"][i]["thickness"] == pytest.approx(0.016)


def test_contact_arrows_point_into_the_object_and_skip_missing_forces():
    arrows = entity(message(), "contacts")["arrows"]
    assert len(arrows) == 1
    a = arrows[0]
    direction = _rotate(a["pose"]["orientation"], [1, 0, 0])  # arrows point along their +x
    to_centre = np.array(STATE["object_pose"][:2]) - STATE["contacts"][0]["position"]
    assert direction[[0, 2]] == pytest.approx(to_centre / np.linalg.norm(to_centre))
    assert a["shaft_length"] + a["head_length"] == pytest.approx(2.0 * 0.01)


def _states(episode, times):
    return [{**copy.deepcopy(STATE), "episode": episode, "sim_time_s": t} for t in times]


def test_replay_lays_the_first_episodes_out_one_after_another():
    written = []
    replay = SceneReplay(lambda topic, msg, t: written.append((topic, msg, t)), GEOMETRY,
                         episodes=2, start_ns=10**18)
    for ep, times in ((1, [0.0, 0.05, 0.1]), (0, [0.0, 0.05]), (2, [0.0, 0.05])):
        for s in reversed(_states(ep, times)):  # any order: held until the episode ends
            replay.on_state(s)
    for ep in (1, 2, 0):
        replay.on_episode({"episode": ep, "group": "easy", "success": ep == 1,
                           "dropped": False, "xg": [0.0, 0.3, 0.1]})
    assert {topic for topic, _, _ in written} == {"/scene"}
    times = [t for _, _, t in written]
    assert len(written) == 5  # episode 2 is beyond the first two
    assert times == sorted(times) and times[0] == 10**18
    assert times[3] - times[2] == 10**9  # the gap after the last snapshot of episode 1
    clears = [bool(m["deletions"]) for _, m, _ in written]
    assert clears == [True, False, False, True, False]  # each episode starts afresh
    captions = [entity(m, "caption")["texts"][0]["text"] for _, m, _ in written]
    assert captions[2].endswith("success") and captions[4].endswith("timeout")
    for _, m, t in written:
        stamp = entity(m, "object")["timestamp"]
        assert stamp["sec"] * 10**9 + stamp["nsec"] == t
    assert not replay.held  # nothing kept after the episodes end


def test_angles_round_trip_through_the_quaternion():
    for th in np.linspace(-math.pi / 2, math.pi / 2, 7):
        box = entity(scene_update({**STATE, "object_pose": [0.0, 0.3, th]}, GEOMETRY, 0),
                     "object")["cubes"][0]
        q = box["pose"]["orientation"]
        assert -2 * math.atan2(q["y"], q["w"]) == pytest.approx(th)
