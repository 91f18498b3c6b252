"""JSON Schemas (draft 2020-12) of every topic in a run log, and a cheap required-keys check."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from inhand_exp.record.scene import scene_update_schema

# Rules every schema here keeps, so that Foxglove can turn it into message definitions:
# each property has exactly one "type" (never a list, never "null"), every object schema has
# "properties" (possibly empty), every array has "items" with one scalar or object type.
# Topics only ever gain properties; a property never changes meaning or units.
# Units are SI: metres (m), radians (rad), seconds (s), newtons (N).

DRAFT_2020_12 = "https://json-schema.org/draft/2020-12/schema"

NON_FINITE_NOTE = (
    "Non-finite numbers (NaN, +-inf) are written as null, so a number field may hold null."
)


def _number(description: str) -> dict[str, Any]:
    return {"type": "number", "description": description}


def _integer(description: str, minimum: int | None = 0) -> dict[str, Any]:
    schema: dict[str, Any] = {"type": "integer", "description": description}
    if minimum is not None:
        schema["minimum"] = minimum
    return schema


def _string(description: str) -> dict[str, Any]:
    return {"type": "string", "description": description}


def _boolean(description: str) -> dict[str, Any]:
    return {"type": "boolean", "description": description}


def _fraction(description: str) -> dict[str, Any]:
    return {"type": "number", "minimum": 0, "maximum": 1, "description": description}


def _pose(description: str) -> dict[str, Any]:
    return {
        "type": "array",
        "description": f"{description}: planar object pose [x (m), z (m), theta (rad)].",
        "items": {"type": "number"},
        "minItems": 3,
        "maxItems": 3,
    }


def _topic(
    title: str, description: str, properties: dict[str, Any], required: list[str]
) -> dict[str, Any]:
    missing = set(required) - set(properties)
    if missing:  # pragma: no cover - guards edits to this module
        raise AssertionError(f"{title}: required keys without a property: {sorted(missing)}")
    return {
        "$schema": DRAFT_2020_12,
        "title": title,
        "description": f"{description} {NON_FINITE_NOTE}",
        "type": "object",
        "properties": properties,
        "required": required,
    }


RUN_CONFIG = _topic(
    "inhand_exp.RunConfig",
    "Written once at the start of a run: everything needed to reproduce it.",
    {
        "config": {
            "type": "object",
            "description": "The resolved Hydra config of the run (interpolations resolved).",
            "properties": {},
        },
        "versions": {
            "type": "object",
            "description": "Installed versions of the packages that decide results, by name.",
            "properties": {},
            "additionalProperties": {"type": "string"},
        },
        "seed": _integer("Master random seed of the run.", minimum=None),
        "mode": _string("What the run does, e.g. train or eval."),
        "overrides": {
            "type": "array",
            "description": "Hydra command-line overrides the run was started with.",
            "items": {"type": "string"},
        },
        "policy_overrides": {
            "type": "array",
            "description": "Overrides of the training run(s) that made the policy this run "
                           "trains or evaluates, as its checkpoint records them; absent when "
                           "the checkpoint predates the record.",
            "items": {"type": "string"},
        },
        "run_dir": _string("Directory the run writes its outputs to."),
        "started_utc": {
            "type": "string",
            "format": "date-time",
            "description": "Wall-clock start time of the run, ISO 8601, UTC.",
        },
        "git": {
            "type": "object",
            "description": "Git state of the source checkout; null when not run from git.",
            "properties": {
                "commit": _string("Commit hash of HEAD."),
                "dirty": _boolean("True when tracked files had uncommitted changes."),
            },
        },
    },
    ["config", "versions", "seed"],
)

TRAIN_ITERATION = _topic(
    "inhand_exp.TrainIteration",
    "One training iteration of the learner (one batch of collected frames and its update).",
    {
        "iteration": _integer("Index of the iteration, from 0."),
        "frames": _integer("Environment frames collected since training started (cumulative)."),
        "wall_s": _number("Wall-clock time since training started (s)."),
        "losses": {
            "type": "object",
            "description": "Loss values of this iteration's update, by loss name (unitless).",
            "properties": {},
            "additionalProperties": {"type": "number"},
        },
        "mean_return": _number("Mean undiscounted return of episodes finished this iteration."),
        "success_rate": _fraction("Fraction of episodes finished this iteration that succeeded."),
        "drop_rate": _fraction("Fraction of episodes finished this iteration that dropped the "
                               "object."),
        "actions_per_s": _number("Throughput: actions executed per second of wall time (1/s)."),
        "collect_s": _number("Wall time this iteration spent collecting its batch (s)."),
        "learn_s": _number("Wall time this iteration spent on the learner's update (s)."),
    },
    ["iteration", "frames"],
)

EVAL_EPISODE = _topic(
    "inhand_exp.EvalEpisode",
    "Outcome of one evaluation episode.",
    {
        "episode": _integer("Index of the episode within its evaluation, from 0."),
        "group": _string("Evaluation group the episode belongs to (e.g. a test condition)."),
        "success": _boolean("True when the object reached the goal pose within tolerance."),
        "dropped": _boolean("True when the object fell out of the hand."),
        "timeout": _boolean("True when the episode ran out of time or actions."),
        "sim_time_s": _number("Simulated duration of the episode (s)."),
        "n_actions": _integer("Number of actions (primitives) executed."),
        "n_invalid": _integer("Number of actions rejected as invalid in their state."),
        "x0": _pose("Initial object pose"),
        "xg": _pose("Goal object pose"),
        "final_pose": _pose("Object pose at the end of the episode"),
        "final_err_m": _number("Position error between final and goal pose (m)."),
        "final_err_rad": _number("Absolute orientation error between final and goal pose (rad)."),
        "needs_flip": _boolean("True when no grasp of the initial posture holds the object at "
                               "the goal (the goal set's own flag)."),
        "lone_down": _boolean("True when the initial posture holds the object at the goal only "
                              "with its lone finger lower on the pole than at the start (the "
                              "goal set's own flag)."),
        "n_flips": _integer("Flips (for the cube: lands) that ended done; absent where the "
                            "learner's actions are not primitives."),
        "object": _string("Name of the object config."),
        "perturb": _string("Name of the perturbation config."),
        "noise": _string("Name of the noise config."),
        "learner": _string("Name of the learner config."),
        "seed": _integer("Random seed of the episode.", minimum=None),
    },
    ["group", "success", "dropped", "timeout", "sim_time_s", "n_actions", "x0", "xg",
     "final_pose"],
)

EPISODE_ACTION = _topic(
    "inhand_exp.EpisodeAction",
    "One high-level action (manipulation primitive) executed in an episode.",
    {
        "episode": _integer("Index of the episode the action belongs to."),
        "step": _integer("Index of the action within its episode, from 0."),
        "action": _integer("Index of the chosen primitive in the action set."),
        "name": _string("Name of the chosen primitive."),
        "valid": _boolean("False when the primitive was not applicable in the current state."),
        "outcome": _string("How the primitive ended: done, infeasible, lost_contact, "
                           "unstable, timeout, link_contact (a link or the palm touched the "
                           "object), rejected (by the filter) or none."),
        "pose_before": _pose("Object pose before the action"),
        "pose_after": _pose("Object pose after the action"),
        "sim_time_s": _number("Simulated time since the episode start when the action ended "
                              "(s)."),
        "reward": _number("Reward received for the action (unitless)."),
    },
    ["episode", "step", "action", "valid", "pose_before", "pose_after"],
)

SIM_STATE = _topic(
    "inhand_exp.SimState",
    "A snapshot of the simulated hand and object.",
    {
        "episode": _integer("Index of the episode the snapshot belongs to."),
        "sim_time_s": _number("Simulated time since the episode start (s)."),
        "object_pose": _pose("Object pose"),
        "joint_q": {
            "type": "array",
            "description": "Joint positions of the hand, in joint order (rad).",
            "items": {"type": "number"},
        },
        "joint_qd": {
            "type": "array",
            "description": "Joint velocities of the hand, in joint order (rad/s).",
            "items": {"type": "number"},
        },
        "contacts": {
            "type": "array",
            "description": "Fingertip-object contacts active at this instant.",
            "items": {
                "type": "object",
                "properties": {
                    "finger": _integer("Index of the finger in contact, from 0."),
                    "position": {
                        "type": "array",
                        "description": "Contact point [x (m), z (m)].",
                        "items": {"type": "number"},
                        "minItems": 2,
                        "maxItems": 2,
                    },
                    "normal_force_n": _number("Normal contact force (N)."),
                    "tangential_force_n": _number("Tangential (friction) contact force (N)."),
                },
                "required": ["finger", "position", "normal_force_n"],
            },
        },
    },
    ["sim_time_s", "object_pose", "joint_q"],
)

TOPIC_SCHEMAS: dict[str, dict[str, Any]] = {
    "/run/config": RUN_CONFIG,
    "/train/iteration": TRAIN_ITERATION,
    "/eval/episode": EVAL_EPISODE,
    "/episode/action": EPISODE_ACTION,
    "/sim/state": SIM_STATE,
    "/scene": scene_update_schema(DRAFT_2020_12, NON_FINITE_NOTE),
}

_REQUIRED: dict[str, tuple[str, ...]] = {
    topic: tuple(schema["required"]) for topic, schema in TOPIC_SCHEMAS.items()
}


def check_required(topic: str, message: Mapping[str, Any]) -> None:
    """Raise ValueError unless ``topic`` is known and ``message`` has all its required keys.

    Only checks key presence (microseconds), not types: full JSON-Schema validation is for tests.
    """
    try:
        required = _REQUIRED[topic]
    except KeyError:
        raise ValueError(
            f"unknown topic {topic!r}; known topics: {', '.join(TOPIC_SCHEMAS)}"
        ) from None
    if not isinstance(message, Mapping):
        raise TypeError(f"{topic} message must be a dict, got {type(message).__name__}")
    missing = [key for key in required if key not in message]
    if missing:
        raise ValueError(f"{topic} message is missing required key(s): {', '.join(missing)}")
