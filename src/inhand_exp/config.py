"""Typed config schemas (Hydra ConfigStore), one documented field each, and their validation."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING, DictConfig, ListConfig, OmegaConf


class ConfigError(ValueError):
    """A composed config holds a value that is physically or logically impossible."""


def spec(default: Any, doc: str, **rules: Any) -> Any:
    """A dataclass field with a docstring and validation rules.

    Rules: ``gt``/``ge``/``le`` (numbers, applied to every element of a list), ``choices`` (allowed
    values), ``length`` (exact list length).
    """
    meta = {"doc": doc, **rules}
    if isinstance(default, list | dict):
        return field(default_factory=lambda: type(default)(default), metadata=meta)
    return field(default=default, metadata=meta)


class Mode(StrEnum):
    demo = "demo"
    train = "train"
    eval = "eval"
    train_eval = "train_eval"
    goals = "goals"


class FilterMode(StrEnum):
    mask = "mask"
    penalty = "penalty"
    off = "off"


class EnvBackend(StrEnum):
    serial = "serial"
    parallel = "parallel"


@dataclass
class SimConfig:
    timestep_s: float = spec(1 / 240, "Physics timestep (s).", gt=0)
    control_substeps: int = spec(2, "Physics steps per update of the torque law: its torques "
                                 "are held for this many steps (1: the controllers run at the "
                                 "physics rate).", ge=1)
    solver_iterations: int = spec(50, "PyBullet constraint-solver iterations per step.", gt=0)
    gravity_mps2: float = spec(9.81, "Gravity magnitude (m/s^2), pointing along -z.", ge=0)


@dataclass
class HandConfig:
    finger_base_x_m: list[float] = spec(
        [-0.12, 0.0, 0.12], "x of each finger's base joint (m), left to right.", length=3
    )
    base_z_m: float = spec(0.0, "z of the finger base joints (m).")
    link_lengths_m: list[float] = spec(
        [0.16, 0.16], "Proximal and distal link lengths (m), joint to joint/tip centre.",
        gt=0, length=2,
    )
    link_masses_kg: list[float] = spec([0.05, 0.05], "Proximal and distal link masses (kg).",
                                       gt=0, length=2)
    link_radius_m: float = spec(0.008, "Radius of the link capsules (m); they collide with the "
                                "object.", gt=0)
    link_clearance_m: float = spec(0.002, "Least gap the controllers keep between a link (or "
                                   "the palm) and the object in every pose they plan (m).", ge=0)
    palm_thickness_m: float = spec(0.02, "Thickness of the palm plate (m); its top face is at "
                                   "base_z_m and the object collides with it.", gt=0)
    palm_overhang_m: float = spec(0.06, "How far the palm plate reaches beyond the outer "
                                  "finger bases (m).", ge=0)
    tip_radius_m: float = spec(0.012, "Radius of the spherical fingertip (m).", gt=0)
    tip_mass_kg: float = spec(0.01, "Mass of the fingertip sphere (kg).", gt=0)
    friction: float = spec(1.0, "Lateral friction coefficient of the fingertips.", ge=0)
    max_torque_nm: float = spec(10.0, "Joint torque limit (N m), applied to every command.", gt=0)
    joint_lower_rad: list[float] = spec([-0.5, -2.8], "Lower joint limits (rad); angles from +x, "
                                        "counter-clockwise.", length=2)
    joint_upper_rad: list[float] = spec([math.pi + 0.5, 2.8], "Upper joint limits (rad); a "
                                        "range of at most 2 pi.", length=2)


@dataclass
class ObjectConfig:
    name: str = spec("pole", "Object shape.", choices=("pole", "cube"))
    length_m: float = spec(0.50, "Extent along the object's long axis (m).", gt=0)
    width_m: float = spec(0.02, "Extent across the long axis, in the hand plane (m).", gt=0)
    depth_m: float = spec(0.05, "Extent along y, out of the hand plane (m).", gt=0)
    mass_kg: float = spec(0.1, "Mass (kg); inertia is that of a uniform box.", gt=0)
    friction: float = spec(1.0, "Lateral friction coefficient of the object surface.", ge=0)


@dataclass
class PerturbConfig:
    name: str = spec("none", "Label of the perturbation, for logs and tables.")
    mass_scale: float = spec(1.0, "Simulated mass / nominal mass.", gt=0)
    width_scale: float = spec(1.0, "Simulated width / nominal width.", gt=0)
    length_scale: float = spec(1.0, "Simulated length / nominal length.", gt=0)


@dataclass
class NoiseConfig:
    name: str = spec("none", "Label of the noise model, for logs and tables.")
    xz_m: float = spec(0.0, "Half-width of uniform noise on observed object x and z (m).", ge=0)
    theta_rad: float = spec(0.0, "Half-width of uniform noise on observed object angle (rad).",
                            ge=0)


@dataclass
class PrimitivesConfig:
    name: str = spec("pole", "Primitive set.", choices=("pole", "cube"))
    repose_dx_m: float = spec(0.01, "Repose step along x (m).", gt=0)
    repose_dz_m: float = spec(0.01, "Repose step along z (m).", gt=0)
    repose_dtheta_rad: float = spec(0.1, "Repose step in angle (rad).", gt=0)
    slide_dc_m: float = spec(0.02, "Slide step of one fingertip along the surface (m).", gt=0)
    end_margin_m: float = spec(0.025, "Distance a slide keeps its fingertip from the model's "
                               "end of the face, beyond the tip's radius (m): room for an "
                               "object shorter than modelled, whose ends no fingertip feels "
                               "until it is past them. A slide back from inside the margin "
                               "is always allowed.", ge=0)
    slide: bool = spec(True, "Offer the slide actions (6 for the pole).")
    flip: bool = spec(True, "Offer flip-left / flip-right (pole).")
    release_land: bool = spec(False, "Offer release / land per finger (cube).")
    land_other_elbow: bool = spec(False, "With release_land, offer also a land per finger "
                                  "that puts it down with its elbow on the other side, "
                                  "nearest its mirror image (any face, the one it left too).")
    flip_end_margin_m: float = spec(0.025, "Room a flipping finger keeps round the object's "
                                    "ends beyond the nominal ones (m), for an object longer "
                                    "than modelled, whose ends no fingertip feels. Taken "
                                    "where a path with it exists; a flip that has none passes "
                                    "the nominal ends.", ge=0)
    repose_duration_s: float = spec(0.5, "Simulated time given to one repose (s).", gt=0)
    slide_duration_s: float = spec(0.5, "Simulated time given to one slide (s).", gt=0)
    flip_duration_s: float = spec(2.0, "Simulated time given to one flip (s).", gt=0)
    release_lift_m: float = spec(0.025, "How far a release lifts the tip off its face (m). "
                                 "A turning cube's corners sweep out to half its diagonal: "
                                 "2.5 cm keeps a 10 cm cube's sweep off the free tip.", gt=0)
    release_duration_s: float = spec(1.0, "Simulated time given to one release (s).", gt=0)
    land_duration_s: float = spec(1.5, "Simulated time given to one land (s).", gt=0)
    settle_early: bool = spec(True, "End a repose or slide once it is past its move, within "
                              "its tolerance and at rest, instead of holding still for the "
                              "rest of its duration.")
    kp: float = spec(400.0, "Object-pose PD stiffness (1/s^2).", ge=0)
    kd: float = spec(40.0, "Object-pose PD damping (1/s).", ge=0)
    min_normal_force_n: float = spec(0.5, "Least normal force at every held contact (N).", ge=0)
    max_normal_force_n: float = spec(50.0, "Most normal force a plan may ask of a contact (N).",
                                     gt=0)
    slide_max_normal_force_n: float = spec(35.0, "Most normal force a slide's plan may ask of "
                                           "a holding finger at one control step (N); a step "
                                           "that needs more halts the slide: every finger "
                                           "holds the object to the end of its time. "
                                           "Such a plan balances the drag by pinching a grasp "
                                           "whose torque rests on friction across the faces, "
                                           "and shoots the object out of the hand.", gt=0)
    friction_margin: float = spec(0.8, "Fraction of the friction cone the controller may use.",
                                  gt=0)
    min_grasp_margin: float = spec(0.02, "Least slack of a grasp's deepest squeeze (per newton "
                                   "of total squeeze) for a repose to move it, or a slide, "
                                   "flip or land to end in it: a weaker grasp holds the object "
                                   "only by squeezing it tens of times its weight.", ge=0)


@dataclass
class GoalsConfig:
    name: str = spec("medium", "Difficulty group.", choices=("easy", "medium", "hard"))
    test_pairs: int = spec(500, "Test (X0, Xg) pairs in the group.", gt=0)
    train_pairs: int = spec(20000, "Training pairs, drawn apart from the test set.", gt=0)
    seed: int = spec(1234, "Seed of the dataset, the same for every learner.", ge=0)
    hard_goal_posture: str = spec("other", "Hard goals are poses held by a grasp of another "
                                  "posture than the start's (other, as the authors' code drew "
                                  "them; arbitrary pairs need a flip too rarely) or any pose "
                                  "the hand holds (any).", choices=("other", "any"))
    hard_flip_share: float = spec(0.25, "Share of a pole's hard test pairs drawn from those "
                                  "that need a flip: pair i is one when floor((i + 1) * share) "
                                  "> floor(i * share) (every 4th at 0.25); the others are "
                                  "drawn as before, and about 13 % of those need a flip too. "
                                  "0: none drawn so (the set before this option). Test sets "
                                  "only; training draws are unchanged.", ge=0, le=1)
    reachable_only: bool = spec(True, "Keep only hard pairs whose goal the action set can "
                                "reach: flips lead to a posture that holds it. With the "
                                "paper's flips (left and right finger) the middle finger never "
                                "changes side, and 17 % of the 'other' hard pairs have goals "
                                "only postures with it on the other side hold; false keeps "
                                "them.")
    x0: list[float] | None = spec(None, "A fixed initial pose [x (m), z (m), theta (rad)] "
                                  "for every pair, training and test, held by one grasp drawn "
                                  "once from goals.seed (the paper's cube study); null: each "
                                  "pair draws its own.", length=3)
    train_groups: list[str] = spec([], "Groups the training episodes are drawn from, "
                                   "uniformly; empty: this group only. 'flip': hard pairs "
                                   "that need a flip (about 13 % of the hard ones); 'lone' "
                                   "(a pole): medium pairs whose lone finger must end lower "
                                   "on the pole (about 13 % of the medium ones).",
                                   choices=("easy", "medium", "hard", "flip", "lone"))


@dataclass
class LearnerConfig:
    name: str = spec(MISSING, "Learner.", choices=("ppo", "ddpg", "search"))


@dataclass
class PPOConfig(LearnerConfig):
    name: str = spec("ppo", "Learner.", choices=("ppo",))
    lr: float = spec(3e-4, "Adam learning rate.", gt=0)
    gamma: float = spec(0.99, "Discount per mid-level action.", gt=0)
    gae_lambda: float = spec(0.95, "GAE lambda.", ge=0)
    clip_epsilon: float = spec(0.2, "PPO ratio clip.", gt=0)
    entropy_coef: float = spec(0.01, "Entropy bonus weight.", ge=0)
    critic_coef: float = spec(0.5, "Value-loss weight.", ge=0)
    hidden: list[int] = spec([256, 256, 256], "Hidden layer sizes of policy and critic.", gt=0)
    frames_per_batch: int = spec(1024, "Mid-level actions collected per iteration.", gt=0)
    epochs: int = spec(4, "Optimisation epochs per batch.", gt=0)
    minibatch_size: int = spec(256, "Minibatch size.", gt=0)
    max_grad_norm: float = spec(1.0, "Gradient clipping norm.", gt=0)
    grasp_features: bool = spec(True, "Also feed the networks each fingertip's place on the "
                                "object (forward kinematics of q in the frame of X_t) and the "
                                "feasibility mask; false: the paper's q, qd, X_t, X_g only.")
    demonstrations: list[str] = spec([], "Files of another policy's episodes (an evaluation "
                                     "with eval.demonstrations=true, e.g. the search's) to "
                                     "clone before PPO starts; only successful episodes count.")
    bc_epochs: int = spec(30, "Passes of behaviour cloning over the demonstrations before the "
                          "first iteration.", ge=0)
    bc_coef: float = spec(1.0, "Weight of the cloning term added to PPO's loss at the start; "
                          "it falls linearly to 0 over bc_frames.", ge=0)
    bc_frames: int = spec(49152, "Frames over which the cloning term's weight falls to 0.",
                          gt=0)


@dataclass
class DDPGConfig(LearnerConfig):
    name: str = spec("ddpg", "Learner.", choices=("ddpg",))
    actor_lr: float = spec(1e-4, "Actor learning rate.", gt=0)
    critic_lr: float = spec(1e-3, "Critic learning rate.", gt=0)
    gamma: float = spec(0.99, "Discount per control step.", gt=0)
    tau: float = spec(0.005, "Target-network soft-update rate.", gt=0)
    hidden: list[int] = spec([256, 256, 256], "Hidden layer sizes.", gt=0)
    buffer_size: int = spec(1_000_000, "Replay buffer capacity (transitions).", gt=0)
    batch_size: int = spec(256, "Minibatch size.", gt=0)
    exploration_std: float = spec(0.1, "Gaussian exploration noise, fraction of max torque.",
                                  ge=0)
    control_period_s: float = spec(1 / 60, "Torque-policy period (s), a whole number of steps.",
                                   gt=0)
    train_pool: int = spec(64, "Training pairs each environment draws and then replays "
                           "uniformly: an end-to-end episode can end in a fraction of a second, "
                           "and drawing a pair takes about 0.2 s.", ge=0)
    warmup_frames: int = spec(10_000, "Frames of uniformly random torques before the policy "
                              "acts (fills the replay buffer).", ge=0)
    frames_per_batch: int = spec(1024, "Frames collected per iteration.", gt=0)
    updates_per_batch: int = spec(256, "Gradient steps per collected batch.", gt=0)
    normalize: bool = spec(True, "Standardise the networks' observation by the warm-up's "
                           "mean and standard deviation (then kept).")


@dataclass
class SearchConfig(LearnerConfig):
    name: str = spec("search", "Learner.", choices=("search",))
    resolution_m: float = spec(0.02, "Grid resolution of object x and z (m); paper: 2 cm.", gt=0)
    resolution_rad: float = spec(0.2, "Grid resolution of the object angle (rad); paper: 0.2.",
                                 gt=0)
    contact_resolution_m: float = spec(0.05, "Grid resolution of contact positions (m); paper: "
                                       "5 cm.", gt=0)
    max_cells: int = spec(200_000_000, "Largest lattice (postures x contacts x poses) the "
                          "search builds; a finer one is refused before it exhausts memory.",
                          gt=0)
    cache_dir: str = spec("logs/cache", "Where built graphs are kept, one file per setting "
                          "(keyed by everything that shapes the graph).")


@dataclass
class TaskConfig:
    filter: FilterMode = spec(FilterMode.mask, "Feasibility filter: mask, penalty (paper), off.")
    no_undo: bool = spec(False, "The feasibility filter also refuses the action that would "
                         "undo the last one carried out (the opposite repose, the same finger's "
                         "slide back), unless no other action is allowed; false: the paper's "
                         "filter.")
    no_undo_flip: bool = spec(False, "The feasibility filter also refuses a flip right after "
                              "the same flip (the object holds still in a flip and the finger "
                              "lands nearest where it was, so the second carries it back), "
                              "unless no other action is allowed; false: the paper's filter.")
    no_repeat_contact: bool = spec(False, "The feasibility filter also refuses an action right "
                                   "after it ended touching a link or the palm (outcome "
                                   "link_contact: the controllers' model allowed a move the "
                                   "real object does not fit, such as a longer pole's end "
                                   "resting on the palm), unless no other action is allowed; "
                                   "false: the paper's filter.")
    touch_finds_length: bool = spec(False, "A link or the palm that touches the object "
                                    "farther from its centre than the controllers' model's "
                                    "ends (by over 5 mm) lengthens the model to there, at both "
                                    "ends, for the rest of the episode: the filter and the "
                                    "primitives then plan on the object as long as touch found "
                                    "it (a longer pole's end no longer meets the links and the "
                                    "palm again and again); false: the model keeps the nominal "
                                    "length.")
    reward_goal: float = spec(5.0, "Reward on reaching the goal.")
    reward_invalid: float = spec(-0.01, "Reward of an infeasible action (penalty mode).")
    reward_flip: float = spec(1.0, "Reward of a useful, successful flip.")
    reward_flip_needed: bool = spec(False, "Pay reward_flip only in episodes whose pair needs a "
                                    "flip (its needs_flip); false: for every useful flip, as "
                                    "the paper.")
    reward_progress: float = spec(0.0, "Shaping: reward per tolerance (1 cm, 0.1 rad) of "
                                  "progress towards the goal; 0 is the paper's reward.")
    reward_route: float = spec(0.0, "Shaping: reward per second of the search graph's "
                               "shortest route to the goal that an action saves (task/route.py; "
                               "the graph of learner=search at its default resolution, kept in "
                               "route_cache_dir); 0 is the paper's reward.", ge=0)
    route_advice: bool = spec(False, "Append the search graph's view of the state to the "
                              "policy's observation: the route time to the goal and, per "
                              "action, how much longer the route is by that action "
                              "(task/route.py RouteAdvice; the graph of route_cache_dir). "
                              "false: the paper's observation.")
    posture_advice: bool = spec(False, "Append two flags to the policy's observation: no "
                                "grasp of the fingers' posture holds the object at the goal "
                                "(a flip is needed), and only grasps with the lone finger "
                                "lower than now do (task/posture_advice.py; from the observed "
                                "state). false: the paper's observation.")
    route_cap_s: float = spec(40.0, "Route times longer than this, and states with no route, "
                              "count as this long (s).", gt=0)
    route_cache_dir: str = spec("logs/cache", "Where the route shaping's graph is kept "
                                "(learner=search's default cache: they share the file).")
    success_tol_m: float = spec(0.01, "Success tolerance on |dx| and |dz| (m).", gt=0)
    success_tol_rad: float = spec(0.1, "Success tolerance on |dtheta| (rad).", gt=0)
    max_actions: int = spec(200, "Time limit in mid-level actions (the authors': 200).", gt=0)
    time_limit_s: float = spec(100.0, "Time limit of an end-to-end (torque) episode in simulated "
                               "seconds: max_actions reposes of primitives.repose_duration_s.",
                               gt=0)
    workspace_x_m: list[float] = spec([-0.05, 0.05], "Range of object x (m) that start and goal "
                                      "poses are drawn from (the authors': +-5 cm).", length=2)
    workspace_z_m: list[float] = spec([0.18, 0.52], "Range of object z (m), the height of its "
                                      "centre above the palm; the hand holds a band inside it.",
                                      length=2)
    workspace_theta_rad: list[float] = spec([-math.pi / 2, math.pi / 2], "Range of the object's "
                                            "tilt from upright (rad; the authors': +-pi/2). "
                                            "Every pose is kept only if a grasp holds it.",
                                            length=2)


@dataclass
class TrainConfig:
    frames: int = spec(1024, "Training budget in mid-level actions (a short default).", gt=0)
    num_envs: int = spec(16, "Environments collecting in parallel.", gt=0)
    workers: int = spec(2, "Worker processes for the environments (<= cores).", gt=0)
    backend: EnvBackend = spec(EnvBackend.parallel, "Batched env: parallel or serial.")
    checkpoint_every: int = spec(1, "Iterations between checkpoints.", gt=0)
    store: str | None = spec(None, "Directory of shared policies (sweeps): each policy (learner, "
                             "object, noise, seed, recipe) is trained there once, under a lock, "
                             "and reused by every run that needs it; None trains in the run "
                             "directory.")


@dataclass
class EvalConfig:
    episodes: int = spec(100, "Episodes per goal group (the paper: 500).", gt=0)
    goals_file: str | None = spec(None, "CSV/Parquet goal set to evaluate on instead.")
    sample: bool = spec(True, "Draw each action from the policy, as it was trained (seeded from "
                        "seed); false: take its most likely action, which can cycle.")
    split: str = spec("test", "Which of the group's pairs to play: test (the benchmark's) or "
                      "train (drawn as the test pairs are, from another stream: for recording "
                      "demonstrations without touching the test pairs).",
                      choices=("test", "train"))
    demonstrations: bool = spec(False, "Also write demonstrations.pt: every step's observation, "
                                "mask and action, with each episode's outcome, for PPO's "
                                "learner.demonstrations.")


@dataclass
class LogConfig:
    file: str = spec("run.mcap", "Log file name inside the run directory.")
    sim_state_hz: float = spec(20.0, "Rate of /sim/state messages (Hz of sim time); 0 = off.",
                               ge=0)
    scene_episodes: int = spec(10, "Evaluation episodes also drawn on /scene (Foxglove's 3D "
                               "panel), one after another; 0 = off. Needs sim_state_hz > 0.",
                               ge=0)
    chunk_size_bytes: int = spec(32 * 1024, "MCAP chunk size (bytes).", gt=0)
    flush_every_s: float = spec(2.0, "Longest wall time between flushes (s).", gt=0)
    progress: bool = spec(True, "Show a progress bar on the terminal.")


@dataclass
class Config:
    sim: SimConfig = MISSING
    hand: HandConfig = MISSING
    object: ObjectConfig = MISSING
    perturb: PerturbConfig = MISSING
    noise: NoiseConfig = MISSING
    primitives: PrimitivesConfig = MISSING
    goals: GoalsConfig = MISSING
    learner: LearnerConfig = MISSING
    task: TaskConfig = field(default_factory=TaskConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    log: LogConfig = field(default_factory=LogConfig)
    seed: int = spec(0, "Seed of everything random in the run.", ge=0)
    mode: Mode = spec(Mode.demo, "What the run does: demo (the packaged Table II policy, or "
                      "checkpoint=, on eval.episodes test pairs of each goal group), train, "
                      "eval, train_eval, or goals (write the goals group's test set of "
                      "eval.episodes pairs to goals.csv, no policy involved).")
    checkpoint: str | None = spec(None, "Policy checkpoint to evaluate or to train on from: a "
                                    "policy.pt, or packaged:NAME for one packaged with "
                                    "inhand-exp (src/inhand_exp/policies/README.md).")
    resume: str | None = spec(None, "Run directory of an interrupted training to continue.")


GROUP_SCHEMAS: dict[str, type] = {
    "sim": SimConfig,
    "hand": HandConfig,
    "object": ObjectConfig,
    "perturb": PerturbConfig,
    "noise": NoiseConfig,
    "primitives": PrimitivesConfig,
    "goals": GoalsConfig,
}
LEARNER_SCHEMAS: dict[str, type] = {"ppo": PPOConfig, "ddpg": DDPGConfig, "search": SearchConfig}


def register_configs() -> None:
    """Store the schemas: ``schema`` for the root, ``<group>/schema`` for each group option."""
    cs = ConfigStore.instance()
    cs.store(name="schema", node=Config)
    for group, node in GROUP_SCHEMAS.items():
        cs.store(group=group, name="schema", node=node)
    for name, node in LEARNER_SCHEMAS.items():
        cs.store(group="learner", name=f"schema_{name}", node=node)


def typed(node: Any, schema: type) -> Any:
    """``node`` as an instance of its dataclass ``schema``: the object itself if it is one, else
    the config node (a structured ``DictConfig`` or a plain mapping, as the worker processes
    get it) converted once, so that hot loops read plain attributes and not OmegaConf's."""
    if isinstance(node, schema):
        return node
    if isinstance(node, DictConfig) and OmegaConf.get_type(node) is schema:
        return OmegaConf.to_object(node)
    names = {f.name for f in dataclasses.fields(schema)}
    items = node.items() if not isinstance(node, DictConfig) else (
        (k, OmegaConf.to_container(v, resolve=True) if OmegaConf.is_config(v) else v)
        for k, v in node.items())
    values = {k: v for k, v in items if k in names}
    for f in dataclasses.fields(schema):  # enums arrive as their names from plain containers
        if f.name in values and isinstance(f.default, StrEnum):
            values[f.name] = type(f.default)(values[f.name])
    return schema(**values)


def validate(cfg: DictConfig) -> None:
    """Reject unknown keys and impossible values, naming the key and the value."""
    _check_node(cfg, "")
    _check_consistency(cfg)


def _check_node(node: DictConfig, path: str) -> None:
    schema = OmegaConf.get_type(node)
    if not dataclasses.is_dataclass(schema):
        return
    fields = {f.name: f for f in dataclasses.fields(schema)}
    for key in node:
        if key not in fields:
            where = f"{path}{key}"
            raise ConfigError(f"unknown key '{where}': {schema.__name__} has no field '{key}' "
                              f"(known: {', '.join(fields)})")
    for name, f in fields.items():
        value = node[name]
        key = f"{path}{name}"
        if isinstance(value, DictConfig):
            _check_node(value, f"{key}.")
            continue
        _check_value(key, value, f.metadata)


def _check_value(key: str, value: Any, rules: Any) -> None:
    if value is None:  # an optional field left unset
        return
    if "length" in rules and len(value) != rules["length"]:
        raise ConfigError(f"{key} must have {rules['length']} entries, got {len(value)}: "
                          f"{list(value)}")
    items = list(enumerate(value)) if isinstance(value, ListConfig) else [(None, value)]
    for i, v in items:
        name = key if i is None else f"{key}[{i}]"
        if isinstance(v, float) and not math.isfinite(v):
            raise ConfigError(f"{name} must be a finite number, got {v}")
        if "gt" in rules and not v > rules["gt"]:
            raise ConfigError(f"{name} must be > {rules['gt']}, got {v}")
        if "ge" in rules and not v >= rules["ge"]:
            raise ConfigError(f"{name} must be >= {rules['ge']}, got {v}")
        if "le" in rules and not v <= rules["le"]:
            raise ConfigError(f"{name} must be <= {rules['le']}, got {v}")
        if "choices" in rules and v not in rules["choices"]:
            raise ConfigError(f"{name} must be one of {list(rules['choices'])}, got {v!r}")


def _check_consistency(cfg: DictConfig) -> None:
    """Cross-field rules: matching object and primitives, whole step ratios, joint limits."""
    if cfg.mode == Mode.demo and cfg.learner.name != "ppo":
        raise ConfigError(f"mode=demo shows the packaged PPO policy; for learner="
                          f"{cfg.learner.name} use mode=train_eval or mode=eval")
    if cfg.mode == Mode.eval and not cfg.checkpoint and cfg.learner.name != "search":
        raise ConfigError("mode=eval needs checkpoint=PATH (a policy.pt of an earlier run)")
    if "frames_per_batch" in cfg.learner and cfg.learner.frames_per_batch % cfg.train.num_envs:
        raise ConfigError(f"learner.frames_per_batch={cfg.learner.frames_per_batch} must be a "
                          f"multiple of train.num_envs={cfg.train.num_envs}")
    if "lone" in cfg.goals.train_groups and cfg.object.name != "pole":
        raise ConfigError(f"goals.train_groups: 'lone' (a pole's lone finger ending lower) "
                          f"has no pairs for object={cfg.object.name}")
    if cfg.learner.name == "search" and cfg.object.length_m <= 2 * cfg.object.width_m:
        raise ConfigError(f"learner=search plans over a pole's two long faces; it has no graph "
                          f"for object={cfg.object.name} (length_m={cfg.object.length_m} is "
                          f"not more than twice width_m={cfg.object.width_m})")
    if cfg.object.name != cfg.primitives.name:
        raise ConfigError(f"primitives={cfg.primitives.name} does not fit object="
                          f"{cfg.object.name}; choose primitives={cfg.object.name}")
    lo, hi = cfg.hand.joint_lower_rad, cfg.hand.joint_upper_rad
    for i, (a, b) in enumerate(zip(lo, hi, strict=True)):
        if not a < b <= a + 2 * math.pi:
            raise ConfigError(f"hand.joint_lower_rad[{i}] < hand.joint_upper_rad[{i}] <= "
                              f"hand.joint_lower_rad[{i}] + 2 pi must hold, got {a}, {b}")
    for key in ("workspace_x_m", "workspace_z_m", "workspace_theta_rad"):
        a, b = cfg.task[key]
        if not a < b:
            raise ConfigError(f"task.{key} must be [low, high] with low < high, got [{a}, {b}]")
    dt = cfg.sim.timestep_s * cfg.sim.control_substeps
    durations = {f"primitives.{k}": cfg.primitives[k]
                 for k in ("repose_duration_s", "slide_duration_s", "flip_duration_s",
                           "release_duration_s", "land_duration_s")}
    if cfg.learner.name == "ddpg":
        durations["learner.control_period_s"] = cfg.learner.control_period_s
    for key, duration in durations.items():
        steps = duration / dt
        if abs(steps - round(steps)) > 1e-6 * max(1.0, steps):
            raise ConfigError(f"{key}={duration} is not a whole number of control periods of "
                              f"sim.timestep_s x sim.control_substeps = {dt} s "
                              f"({steps:.4f} periods)")
