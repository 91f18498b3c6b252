"""PPO for the mid-level policy (paper section IV-A): TorchRL collector, GAE and ClipPPOLoss.

The policy is a masked categorical over the discrete actions (infeasible actions get no
probability), the critic a value network; both are 3 x 256 MLPs as in the paper. Training reports
through ``progress(iteration, metrics)`` and never imports the logger; the metrics include the
wall time of the iteration's collection (``collect_s``) and of its update (``learn_s``). A
checkpoint holds everything needed to resume (networks, optimiser, counters, RNG states) as
tensors and plain numbers, so it loads with ``torch.load(weights_only=True)``. With
demonstrations (``learner.demonstrations``) the actor is cloned from them before the first
iteration, and a fading cloning term joins the loss.
"""

from __future__ import annotations

import time
from pathlib import Path

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.envs import EnvBase
from torchrl.modules import MLP, MaskedCategorical, ProbabilisticActor, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from inhand_exp.config import PPOConfig, typed
from inhand_exp.envs.primitive_env import PrimitiveEnv
from inhand_exp.envs.specs import OBS_DIM, advice_size
from inhand_exp.learn.checkpoint import (
    CheckpointError,
    read_checkpoint,
    restore,
    save_checkpoint,
    stamped,
    trained_with,
)
from inhand_exp.learn.demonstrations import clone, cloning_loss, load_demonstrations
from inhand_exp.learn.features import HandGeometry, ObservationFeatures
from inhand_exp.learn.registry import Progress
from inhand_exp.task.actions import action_table


class FeatureMLP(nn.Module):
    """``ObservationFeatures`` followed by an MLP with tanh activations."""

    def __init__(self, features: ObservationFeatures, out: int, hidden: tuple[int, ...]):
        super().__init__()
        self.features = features
        self.mlp = MLP(in_features=features.out_features, out_features=out,
                       num_cells=list(hidden), activation_class=nn.Tanh)

    def forward(self, obs: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        return self.mlp(self.features(obs, mask))


def make_networks(obs_dim: int, n_actions: int, hidden: tuple[int, ...],
                  hand: HandGeometry | None = None) -> tuple[ProbabilisticActor, ValueOperator]:
    """Masked categorical policy and value critic over ``observation`` (see ``features``).

    With ``hand`` both networks also see the fingertips on the object and the action mask.
    """
    keys = ["observation"] if hand is None else ["observation", "action_mask"]

    def net(out: int) -> nn.Module:
        features = ObservationFeatures(obs_dim, hand, 0 if hand is None else n_actions)
        return FeatureMLP(features, out, hidden)

    logits = TensorDictModule(net(n_actions), in_keys=keys, out_keys=["logits"])
    actor = ProbabilisticActor(logits, in_keys={"logits": "logits", "mask": "action_mask"},
                               distribution_class=MaskedCategorical, return_log_prob=True)
    critic = ValueOperator(net(1), in_keys=keys)
    return actor, critic


def from_config(cfg) -> PPO:
    """The mid-level PPO learner of ``cfg`` (the ``learner.ppo`` entry of the registry)."""
    params = typed(cfg.learner, PPOConfig)
    hand = HandGeometry.from_config(cfg.hand) if params.grasp_features else None
    obs_dim, n_actions = OBS_DIM + advice_size(cfg), len(action_table(cfg.primitives))
    demos = (load_demonstrations(params.demonstrations, obs_dim, n_actions)
             if params.demonstrations else None)
    return PPO(obs_dim, n_actions, params, hand, demos)


class PPO:
    """Networks, loss and optimiser; ``train`` runs the collector loop, ``state_dict`` resumes.

    A ``learn.registry.Learner``: it acts in the batched mid-level environment.
    """

    per_action_log = True
    stochastic = True  # a categorical distribution over the actions
    env_class = PrimitiveEnv  # the batched mid-level environment

    def __init__(self, obs_dim: int, n_actions: int, params: PPOConfig,
                 hand: HandGeometry | None = None, demos: TensorDict | None = None):
        self.params, self.obs_dim, self.n_actions = params, obs_dim, n_actions
        self.demos = demos  # steps of another policy's successful episodes (demonstrations)
        self.grasp_features = hand is not None
        self.actor, self.critic = make_networks(obs_dim, n_actions, tuple(params.hidden), hand)
        self.advantage = GAE(gamma=params.gamma, lmbda=params.gae_lambda,
                             value_network=self.critic)
        self.loss = ClipPPOLoss(self.actor, self.critic, clip_epsilon=params.clip_epsilon,
                                entropy_coeff=params.entropy_coef,
                                critic_coeff=params.critic_coef, normalize_advantage=True)
        self.optim = torch.optim.Adam(self.loss.parameters(), lr=params.lr)
        self.iteration, self.frames = 0, 0
        self.trained_with: list[str] | None = None

    @property
    def policy(self) -> ProbabilisticActor:
        return self.actor

    def train(self, env: EnvBase, total_frames: int, progress: Progress | None = None,
              checkpoint: Path | None = None, checkpoint_every: int = 10) -> None:
        """Collect ``total_frames`` more actions (whole batches) from ``env``, learn from them."""
        p = self.params
        batches = -(-total_frames // p.frames_per_batch)
        cloned, clone_s = {}, 0.0
        if self.demos is not None and self.iteration == 0 and p.bc_epochs > 0:
            t = time.perf_counter()
            # reported with the first iteration, its wall time in that iteration's learning
            cloned = {"loss_bc_clone": clone(self.actor, self.demos, p.bc_epochs,
                                             p.minibatch_size, self.optim, p.max_grad_norm)}
            clone_s = time.perf_counter() - t
        collector = Collector(env, self.actor, frames_per_batch=p.frames_per_batch,
                              total_frames=batches * p.frames_per_batch,
                              auto_register_policy_transforms=False)  # not recurrent
        try:
            t = time.perf_counter()
            for batch in collector:
                collected = time.perf_counter()
                metrics = self._update(batch)
                collector.update_policy_weights_()
                learned = time.perf_counter()
                self.iteration += 1
                self.frames += batch.numel()
                if progress is not None:
                    progress(self.iteration, {"frames": self.frames, **metrics, **cloned,
                                              "collect_s": collected - t,
                                              "learn_s": learned - collected + clone_s})
                cloned, clone_s = {}, 0.0
                if checkpoint is not None and self.iteration % checkpoint_every == 0:
                    self.save(checkpoint)
                t = time.perf_counter()
        finally:
            collector.shutdown()
        if checkpoint is not None:
            self.save(checkpoint)

    def bc_weight(self) -> float:
        """The cloning term's weight now: ``bc_coef`` falling linearly to 0 over
        ``bc_frames`` frames; 0 without demonstrations."""
        if self.demos is None:
            return 0.0
        p = self.params
        return p.bc_coef * max(0.0, 1.0 - self.frames / p.bc_frames)

    def _update(self, batch) -> dict[str, float]:
        p = self.params
        with torch.no_grad():
            self.advantage(batch)
        flat = batch.reshape(-1)
        losses, bc = [], []
        weight = self.bc_weight()
        for _ in range(p.epochs):
            for idx in torch.randperm(len(flat)).split(p.minibatch_size):
                out = self.loss(flat[idx])
                total = out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]
                if weight > 0:
                    demo = self.demos[torch.randint(len(self.demos), (len(idx),))]
                    term = cloning_loss(self.actor, demo)
                    total = total + weight * term
                    bc.append(float(term.detach()))
                self.optim.zero_grad()
                total.backward()
                nn.utils.clip_grad_norm_(self.loss.parameters(), p.max_grad_norm)
                self.optim.step()
                losses.append([float(out[k].detach()) for k in ("loss_objective", "loss_critic",
                                                       "loss_entropy")])
        done = batch["next", "done"].squeeze(-1)
        ends = max(int(done.sum()), 1)
        mean = torch.tensor(losses).mean(0).tolist()
        cloning = {"loss_bc": sum(bc) / len(bc), "bc_weight": weight} if bc else {}
        return {"loss_objective": mean[0], "loss_critic": mean[1], "loss_entropy": mean[2],
                **cloning,
                "mean_reward": float(batch["next", "reward"].mean()),
                "episodes": float(done.sum()),
                "success_rate": float(batch["next", "success"].squeeze(-1)[done].sum()) / ends,
                "drop_rate": float(batch["next", "dropped"].squeeze(-1)[done].sum()) / ends}

    # --- checkpoints --------------------------------------------------------------------

    def state_dict(self) -> dict:
        return {"actor": self.actor.state_dict(), "critic": self.critic.state_dict(),
                "optim": self.optim.state_dict(), "iteration": self.iteration,
                "frames": self.frames, "obs_dim": self.obs_dim, "n_actions": self.n_actions,
                "grasp_features": self.grasp_features, "learner": "ppo",
                "torch_rng": torch.get_rng_state()}

    def save(self, path: Path) -> None:
        save_checkpoint(stamped(self.state_dict(), self.trained_with), path)

    def load(self, path: Path) -> None:
        """Resume from ``path`` (or, from a packaged policy that holds the actor alone, only
        act); a checkpoint for other observation or action sizes is refused."""
        state = read_checkpoint(path, "ppo")
        if (state.get("obs_dim"), state.get("n_actions")) != (self.obs_dim, self.n_actions):
            raise CheckpointError(
                f"checkpoint {path} is for {state.get('obs_dim')} observations and "
                f"{state.get('n_actions')} actions; this configuration has {self.obs_dim} and "
                f"{self.n_actions} (task.route_advice=true adds {1 + self.n_actions} "
                f"observations to the paper's {OBS_DIM}, task.posture_advice=true 2)")
        saved = bool(state.get("grasp_features", False))
        if saved != self.grasp_features:
            raise CheckpointError(
                f"checkpoint {path} was trained with learner.grasp_features={saved}; this "
                f"configuration has learner.grasp_features={self.grasp_features}")

        def load() -> None:
            self.actor.load_state_dict(state["actor"])
            if "critic" in state:  # a packaged policy holds the actor alone: it only acts
                self.critic.load_state_dict(state["critic"])
                self.optim.load_state_dict(state["optim"])
                torch.set_rng_state(state["torch_rng"])

        restore(path, load)
        self.iteration, self.frames = int(state["iteration"]), int(state["frames"])
        self.trained_with = trained_with(state)
