"""The scene of a run, built in one place from the typed config.

A scene is the simulated world and everything the controllers and the task need beside it:

- ``model``: the hand and the *nominal* object, what the controllers and the feasibility filter
  know (config ``object``);
- ``true_model``: the hand and the *simulated* object (``object`` scaled by ``perturb``), used
  only to put the fingertips on its real surface at a reset;
- ``prim``: the primitives' durations, steps, gains and force limits (``primitives``);
- ``rules``: tolerances, rewards, time limit and workspace (``task``);
- ``noise``: half-widths of the uniform noise on the observed object pose (``noise``);
- ``workspace``: the bounds that poses are drawn from.

Every environment and the benchmarks build their world here, so the "nominal model, perturbed
simulation" contract of the robustness study has one implementation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from inhand_exp.config import (
    HandConfig,
    NoiseConfig,
    ObjectConfig,
    PerturbConfig,
    PrimitivesConfig,
    SimConfig,
    TaskConfig,
    typed,
)
from inhand_exp.control.execute import Observation
from inhand_exp.control.hand import HandModel
from inhand_exp.control.sample import Workspace
from inhand_exp.sim.world import ObjectSpec, World


def true_object(obj: ObjectConfig, perturb: PerturbConfig) -> ObjectConfig:
    """The object the simulator holds: the nominal one scaled by ``perturb``."""
    return ObjectConfig(obj.name, obj.length_m * perturb.length_scale,
                        obj.width_m * perturb.width_scale, obj.depth_m,
                        obj.mass_kg * perturb.mass_scale, obj.friction)


@dataclass
class Scene:
    world: World
    model: HandModel
    true_model: HandModel
    prim: PrimitivesConfig
    rules: TaskConfig
    noise: np.ndarray
    workspace: Workspace

    def observe(self, rng: np.random.Generator) -> tuple[Observation, np.ndarray, np.ndarray]:
        """What the controllers and the policy see (true joints, the object pose with noise),
        the noise drawn, and the true pose."""
        pose, twist = self.world.object_state()
        q, qd = self.world.joint_state()
        offset = rng.uniform(-self.noise, self.noise) if self.noise.any() else np.zeros(3)
        return Observation(q, qd, pose + offset, twist, 0.0), offset, pose

    def close(self) -> None:
        self.world.close()


def build_scene(cfg, perturb: PerturbConfig | None = None,
                noise: NoiseConfig | None = None) -> Scene:
    """The scene of ``cfg`` (a composed config, or the plain dict a worker process gets).

    ``perturb`` and ``noise`` replace the config's own (the benchmarks sweep them).
    """
    sim, hand = typed(cfg["sim"], SimConfig), typed(cfg["hand"], HandConfig)
    obj = typed(cfg["object"], ObjectConfig)
    perturb = perturb or typed(cfg["perturb"], PerturbConfig)
    noise = noise or typed(cfg["noise"], NoiseConfig)
    world = World(sim, hand, ObjectSpec.from_config(obj, perturb))
    g = sim.gravity_mps2
    rules = typed(cfg["task"], TaskConfig)
    return Scene(world=world,
                 model=HandModel.from_config(hand, obj, g),
                 true_model=HandModel.from_config(hand, true_object(obj, perturb), g),
                 prim=typed(cfg["primitives"], PrimitivesConfig),
                 rules=rules,
                 noise=np.array([noise.xz_m, noise.xz_m, noise.theta_rad]),
                 workspace=Workspace.from_config(rules))
