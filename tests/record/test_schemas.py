"""Topic schemas: valid draft 2020-12, usable by Foxglove, and strict enough to catch mistakes."""

from __future__ import annotations

import copy
from typing import Any

import jsonschema
import pytest

from inhand_exp.record import TOPIC_SCHEMAS
from inhand_exp.record.scene import SceneGeometry, scene_update
from inhand_exp.record.schemas import check_required

TOPICS = ["/run/config", "/train/iteration", "/eval/episode", "/episode/action", "/sim/state",
          "/scene"]

EXAMPLES: dict[str, dict[str, Any]] = {
    "/run/config": {
        "config": {"seed": 7, "mode": "train", "object": {"name": "cube", "size_m": 0.05},
                   "log": {"file": "run.mcap", "chunk_size_bytes": 32768, "flush_every_s": 2.0}},
        "versions": {"python": "3.11.9", "mcap": "1.6.0", "numpy": "2.1.0"},
        "seed": 7,
        "mode": "train",
        "overrides": ["object=cube", "seed=7"],
        "run_dir": "logs/2025-01-01/12-00-00",
        "started_utc": "2025-01-01T12:00:00+00:00",
        "git": {"commit": "0123456789abcdef0123456789abcdef01234567", "dirty": False},
    },
    "/train/iteration": {
        "iteration": 12, "frames": 24576, "wall_s": 301.5,
        "losses": {"actor": 0.42, "critic": 1.7, "entropy": -0.03},
        "mean_return": -3.25, "success_rate": 0.375, "drop_rate": 0.125, "actions_per_s": 81.0,
    },
    "/eval/episode": {
        "episode": 3, "group": "unseen_objects", "success": True, "dropped": False,
        "timeout": False, "sim_time_s": 4.2, "n_actions": 9, "n_invalid": 1,
        "x0": [0.0, 0.12, 0.0], "xg": [0.01, 0.13, 1.5708], "final_pose": [0.011, 0.129, 1.55],
        "final_err_m": 0.0014, "final_err_rad": 0.0208, "object": "cube", "perturb": "none",
        "noise": "low", "learner": "ppo", "seed": 1003,
    },
    "/episode/action": {
        "episode": 3, "step": 4, "action": 2, "name": "rotate_ccw", "valid": True,
        "outcome": "done", "pose_before": [0.0, 0.12, 0.0], "pose_after": [0.0, 0.12, 0.39],
        "sim_time_s": 1.8, "reward": -0.1,
    },
    "/sim/state": {
        "episode": 3, "sim_time_s": 1.804, "object_pose": [0.0, 0.12, 0.39],
        "joint_q": [0.1, -0.4, 0.9, 0.1, -0.4, 0.9, 0.0, 0.3, 0.2],
        "joint_qd": [0.0] * 9,
        "contacts": [
            {"finger": 0, "position": [0.02, 0.11], "normal_force_n": 2.5,
             "tangential_force_n": 0.4},
            {"finger": 2, "position": [-0.02, 0.13], "normal_force_n": 2.1,
             "tangential_force_n": 0.1},
        ],
    },
}
EXAMPLES["/scene"] = scene_update(
    EXAMPLES["/sim/state"],
    SceneGeometry.from_config({"hand": {"finger_base_x_m": [-0.12, 0.0, 0.12],
                                        "link_lengths_m": [0.16, 0.16], "tip_radius_m": 0.012},
                               "object": {"width_m": 0.02, "length_m": 0.5}}),
    1_735_732_800_000_000_000, goal=[0.0, 0.3, 0.2], caption="episode 3", clear=True)

# One plausible mistake per topic that the schema must reject.
MISTAKES = [
    ("/run/config", "seed", "7"),
    ("/train/iteration", "frames", 1.5),
    ("/eval/episode", "final_pose", [0.0, 0.1]),
    ("/episode/action", "valid", "yes"),
    ("/sim/state", "contacts", [{"finger": 0, "position": [0.0, 0.1, 0.2],
                                 "normal_force_n": 1.0}]),
    ("/scene", "entities", [{"id": "object", "frame_id": "world",
                             "cubes": [{"size": {"x": 0.02, "y": 0.05, "z": 0.5}}]}]),
]

UNITS = {"_s": "(s)", "_m": "(m)", "_rad": "(rad)", "_n": "(N)"}


def validator(topic: str) -> jsonschema.Draft202012Validator:
    return jsonschema.Draft202012Validator(
        TOPIC_SCHEMAS[topic], format_checker=jsonschema.Draft202012Validator.FORMAT_CHECKER
    )


def test_topics_are_the_documented_set() -> None:
    assert list(TOPIC_SCHEMAS) == TOPICS


@pytest.mark.parametrize("topic", TOPICS)
def test_schema_is_valid_draft_2020_12(topic: str) -> None:
    schema = TOPIC_SCHEMAS[topic]
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert schema["type"] == "object"
    assert schema["title"] and schema["description"]
    assert set(schema["required"]) <= set(schema["properties"])
    assert schema.get("additionalProperties", True) is not False  # topics may grow


def _properties(schema: dict[str, Any], where: str) -> list[tuple[str, dict[str, Any]]]:
    """(path, schema) of every property, nested objects and arrays of objects included."""
    found = []
    for name, prop in schema.get("properties", {}).items():
        found.append((f"{where}.{name}", prop))
        found += _properties(prop, f"{where}.{name}")
        found += _properties(prop.get("items", {}), f"{where}.{name}[]")
    return found


@pytest.mark.parametrize("topic", TOPICS)
def test_every_property_is_described_with_units(topic: str) -> None:
    for path, prop in _properties(TOPIC_SCHEMAS[topic], topic):
        name = path.rsplit(".", 1)[1]
        assert prop.get("description"), f"{path} has no description"
        if name.endswith("_per_s"):
            assert "(1/s)" in prop["description"], f"{path} does not say (1/s)"
            continue
        for suffix, unit in UNITS.items():
            if name.endswith(suffix):
                assert unit in prop["description"], f"{path} does not say {unit}"
        if name in ("x0", "xg", "final_pose", "pose_before", "pose_after", "object_pose"):
            assert "(m)" in prop["description"] and "(rad)" in prop["description"], path


@pytest.mark.parametrize("topic", TOPICS)
def test_realistic_example_validates(topic: str) -> None:
    validator(topic).validate(EXAMPLES[topic])
    check_required(topic, EXAMPLES[topic])


@pytest.mark.parametrize("topic", TOPICS)
def test_extra_properties_are_allowed(topic: str) -> None:
    validator(topic).validate({**EXAMPLES[topic], "added_later": [1, 2, 3]})


@pytest.mark.parametrize(("topic", "key", "bad"), MISTAKES)
def test_schema_rejects_wrong_types(topic: str, key: str, bad: Any) -> None:
    message = copy.deepcopy(EXAMPLES[topic])
    message[key] = bad
    with pytest.raises(jsonschema.ValidationError):
        validator(topic).validate(message)


@pytest.mark.parametrize("topic", TOPICS)
def test_missing_required_key_is_rejected_and_named(topic: str) -> None:
    for key in TOPIC_SCHEMAS[topic]["required"]:
        message = {k: v for k, v in EXAMPLES[topic].items() if k != key}
        assert not validator(topic).is_valid(message)
        with pytest.raises(ValueError, match=rf"{topic}.*\b{key}\b"):
            check_required(topic, message)


def test_check_required_names_every_missing_key() -> None:
    with pytest.raises(ValueError, match="episode, step, action, valid, pose_before, pose_after"):
        check_required("/episode/action", {"name": "rotate_ccw"})


def test_check_required_rejects_unknown_topic_and_lists_known_ones() -> None:
    with pytest.raises(ValueError, match=r"'/sim/stat'.*/run/config.*/sim/state"):
        check_required("/sim/stat", {})


def test_check_required_rejects_non_dict() -> None:
    with pytest.raises(TypeError, match="/sim/state"):
        check_required("/sim/state", [1, 2, 3])  # type: ignore[arg-type]


def _foxglove_parse(schema: dict[str, Any], where: str) -> None:
    """The rules of Foxglove's JSON-Schema parser (mcap-support/src/parseJsonSchema.ts).

    Foxglove throws, and shows the topic as broken, on anything else.
    """
    scalars = {"boolean", "string", "number", "integer"}
    assert schema.get("type") == "object", f"{where}: not type object"
    assert isinstance(schema.get("properties"), dict), f"{where}: object without properties"
    for name, prop in schema["properties"].items():
        path = f"{where}.{name}"
        kind = prop.get("type")
        assert "oneOf" not in prop, f"{path}: oneOf"
        assert prop.get("contentEncoding") in (None, "base64"), f"{path}: contentEncoding"
        if kind == "object":
            _foxglove_parse(prop, path)
        elif kind == "array":
            items = prop.get("items")
            assert isinstance(items, dict), f"{path}: array without items schema"
            if items.get("type") == "object":
                _foxglove_parse(items, path)
            else:
                assert items.get("type") in scalars, f"{path}: item type {items.get('type')!r}"
        else:
            assert kind in scalars, f"{path}: type {kind!r} (Foxglove needs exactly one type)"


@pytest.mark.parametrize("topic", TOPICS)
def test_foxglove_can_parse_schema(topic: str) -> None:
    _foxglove_parse(TOPIC_SCHEMAS[topic], topic)
