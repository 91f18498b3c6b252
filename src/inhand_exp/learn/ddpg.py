"""DDPG, the end-to-end baseline (paper section IV-A): joint torques from the observation.

TorchRL's ``DDPGLoss`` with target networks for actor and critic (soft updates, ``tau``), a
replay buffer, and Gaussian exploration noise of ``exploration_std`` x the torque limit added to
the actor's action (clipped to the limits). The actor and the critic are 3 x 256 MLPs as in the
paper; the actor ends in a tanh scaled to the torque limits. The first ``warmup_frames`` are
collected with uniformly random torques. Each iteration collects ``frames_per_batch`` frames
from the batched ``TorqueEnv`` and takes ``updates_per_batch`` gradient steps.

Both networks standardise the observation first (``normalize``, as DDPG's authors did with
batch normalisation of the state input): its mean and standard deviation are measured once, on
the warm-up's transitions before the first gradient step, and then kept, as buffers saved
with the networks. The critic also
sees the action as a fraction of the torque limit. Without it, joint velocities of 60-100 rad/s
(the fingers under random torques) reach the first layers unscaled.

It is a ``learn.registry.Learner``: it reports through ``progress(iteration, metrics)``, and its
checkpoint (networks, targets, optimisers, counters, RNG state; plain tensors, loadable with
``weights_only=True``) resumes training. The replay buffer is not saved: a resumed run refills
it (with the current policy) before it learns again.
"""

from __future__ import annotations

import time
from pathlib import Path

import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import Bounded, LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs import EnvBase
from torchrl.modules import MLP, AdditiveGaussianModule, TanhModule, ValueOperator
from torchrl.objectives import DDPGLoss, SoftUpdate

from inhand_exp.config import DDPGConfig, HandConfig, typed
from inhand_exp.envs.specs import OBS_DIM
from inhand_exp.envs.torque_env import TorqueEnv
from inhand_exp.learn.checkpoint import (
    CheckpointError,
    read_checkpoint,
    restore,
    save_checkpoint,
    stamped,
    trained_with,
)
from inhand_exp.learn.registry import Progress

KEEP = ("observation", "action", ("next", "observation"), ("next", "reward"),
        ("next", "done"), ("next", "terminated"), ("next", "success"), ("next", "dropped"))


class Standardize(nn.Module):
    """(x - mean) / std with the statistics of the data it was ``fit`` on (identity before)."""

    def __init__(self, n: int):
        super().__init__()
        self.register_buffer("loc", torch.zeros(n))
        self.register_buffer("scale", torch.ones(n))
        self.register_buffer("fitted", torch.zeros((), dtype=torch.bool))

    def fit(self, x: torch.Tensor, floor: float = 1e-2) -> None:
        self.loc.copy_(x.mean(0))
        self.scale.copy_(x.std(0).clamp_min(floor))
        self.fitted.fill_(True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.loc) / self.scale


class Critic(nn.Module):
    """Q(observation, action) from the standardised observation and the action as a fraction
    of the torque limit."""

    def __init__(self, obs_dim: int, n_joints: int, max_torque: float, hidden: list[int]):
        super().__init__()
        self.norm = Standardize(obs_dim)
        self.max_torque = max_torque
        self.mlp = MLP(in_features=obs_dim + n_joints, out_features=1, num_cells=hidden,
                       activation_class=nn.ReLU)

    def forward(self, observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self.mlp(torch.cat([self.norm(observation), action / self.max_torque], -1))


def from_config(cfg) -> DDPG:
    """The DDPG learner of ``cfg`` (the ``ddpg`` entry of the registry)."""
    hand = typed(cfg.hand, HandConfig)
    return DDPG(OBS_DIM, 6, float(hand.max_torque_nm), typed(cfg.learner, DDPGConfig))


class DDPG:
    """Actor, critic, their targets, optimisers and the replay buffer."""

    per_action_log = False  # one action per control period: /eval/episode only
    stochastic = False  # the actor's torques; exploration noise is for training only
    env_class = TorqueEnv

    def __init__(self, obs_dim: int, n_joints: int, max_torque: float, params: DDPGConfig):
        self.params, self.obs_dim, self.n_joints = params, obs_dim, n_joints
        self.max_torque = max_torque
        spec = Bounded(-max_torque, max_torque, shape=(n_joints,), dtype=torch.float32)
        hidden = list(params.hidden)
        critic = Critic(obs_dim, n_joints, max_torque, hidden)
        self.norms = (Standardize(obs_dim), critic.norm)  # the actor's and the critic's
        self.actor = TensorDictSequential(
            TensorDictModule(nn.Sequential(self.norms[0], MLP(
                in_features=obs_dim, out_features=n_joints, num_cells=hidden,
                activation_class=nn.ReLU)), in_keys=["observation"], out_keys=["param"]),
            TanhModule(in_keys=["param"], out_keys=["action"], spec=spec))
        self.critic = ValueOperator(critic, in_keys=["observation", "action"])
        self.loss = DDPGLoss(self.actor, self.critic, delay_actor=True, delay_value=True)
        self.loss.make_value_estimator(gamma=params.gamma)
        self.target = SoftUpdate(self.loss, tau=params.tau)
        self.explore = TensorDictSequential(self.actor, AdditiveGaussianModule(
            spec=spec, sigma_init=params.exploration_std * max_torque,
            sigma_end=params.exploration_std * max_torque, annealing_num_steps=1,
            std=1.0))
        self.optim_actor = torch.optim.Adam(self.loss.actor_network_params.values(True, True),
                                            lr=params.actor_lr)
        self.optim_critic = torch.optim.Adam(self.loss.value_network_params.values(True, True),
                                             lr=params.critic_lr)
        self.buffer = TensorDictReplayBuffer(
            storage=LazyTensorStorage(params.buffer_size), batch_size=params.batch_size)
        self.iteration, self.frames = 0, 0
        self.trained_with: list[str] | None = None

    @property
    def policy(self) -> TensorDictSequential:
        return self.actor

    def train(self, env: EnvBase, total_frames: int, progress: Progress | None = None,
              checkpoint: Path | None = None, checkpoint_every: int = 10) -> None:
        """Collect ``total_frames`` more frames (whole batches) from ``env``, learning as it
        goes; random torques until the buffer holds ``warmup_frames`` (rounded up to whole
        batches)."""
        p = self.params
        batches = -(-total_frames // p.frames_per_batch)
        # random torques in whole batches, as the collector counts them
        warm = -(-max(0, p.warmup_frames - self.frames) // p.frames_per_batch) * p.frames_per_batch
        collector = Collector(env, self.explore, frames_per_batch=p.frames_per_batch,
                              total_frames=batches * p.frames_per_batch,
                              init_random_frames=warm, auto_register_policy_transforms=False)
        try:
            t = time.perf_counter()
            for batch in collector:
                collected = time.perf_counter()
                self.buffer.extend(batch.reshape(-1).select(*KEEP))
                if p.normalize and not self.fitted and len(self.buffer) >= max(warm, 2):
                    self._fit()  # once, on the warm-up, before the first gradient step
                ready = len(self.buffer) >= p.batch_size and (self.fitted or not p.normalize)
                metrics = self._update(batch) if ready else {}
                collector.update_policy_weights_()
                learned = time.perf_counter()
                self.iteration += 1
                self.frames += batch.numel()
                if progress is not None:
                    progress(self.iteration, {"frames": self.frames, **_rates(batch), **metrics,
                                              "collect_s": collected - t,
                                              "learn_s": learned - collected})
                if checkpoint is not None and self.iteration % checkpoint_every == 0:
                    self.save(checkpoint)
                t = time.perf_counter()
        finally:
            collector.shutdown()
        if checkpoint is not None:
            self.save(checkpoint)

    @property
    def fitted(self) -> bool:
        return bool(self.norms[0].fitted)

    def _fit(self) -> None:
        """Standardise the observation by the replay buffer's statistics (the warm-up's), in
        the actor and the critic and in their targets."""
        obs = self.buffer[:]["observation"].float()
        for norm in self.norms:
            norm.fit(obs)
        loss = self.loss
        for live, target in ((loss.actor_network_params, loss.target_actor_network_params),
                             (loss.value_network_params, loss.target_value_network_params)):
            target.data.copy_(live.data)

    def _update(self, batch) -> dict[str, float]:
        sums = torch.zeros(2)
        n = self.params.updates_per_batch
        for _ in range(n):
            sample = self.buffer.sample()
            out = self.loss(sample)  # the actor's loss sees the critic's parameters detached
            self.optim_critic.zero_grad()
            self.optim_actor.zero_grad()
            (out["loss_value"] + out["loss_actor"]).backward()
            self.optim_critic.step()
            self.optim_actor.step()
            self.target.step()
            sums += torch.stack([out["loss_actor"].detach(), out["loss_value"].detach()])
        return {"loss_actor": float(sums[0]) / n, "loss_value": float(sums[1]) / n}

    # --- checkpoints --------------------------------------------------------------------

    def state_dict(self) -> dict:
        return {"loss": self.loss.state_dict(), "optim_actor": self.optim_actor.state_dict(),
                "optim_critic": self.optim_critic.state_dict(), "iteration": self.iteration,
                "frames": self.frames, "obs_dim": self.obs_dim, "n_joints": self.n_joints,
                "learner": "ddpg", "torch_rng": torch.get_rng_state()}

    def save(self, path: Path) -> None:
        save_checkpoint(stamped(self.state_dict(), self.trained_with), path)

    def load(self, path: Path) -> None:
        state = read_checkpoint(path, "ddpg")
        if (state.get("obs_dim"), state.get("n_joints")) != (self.obs_dim, self.n_joints):
            raise CheckpointError(f"checkpoint {path} is for {state.get('obs_dim')} "
                                  f"observations and {state.get('n_joints')} joints")

        def load() -> None:
            self.loss.load_state_dict(state["loss"])
            self.optim_actor.load_state_dict(state["optim_actor"])
            self.optim_critic.load_state_dict(state["optim_critic"])
            torch.set_rng_state(state["torch_rng"])

        restore(path, load)
        self.iteration, self.frames = int(state["iteration"]), int(state["frames"])
        self.trained_with = trained_with(state)


def _rates(batch) -> dict[str, float]:
    """Return, success and drop rates of the episodes that ended in ``batch``."""
    done = batch["next", "done"].squeeze(-1)
    ends = max(int(done.sum()), 1)
    return {"mean_reward": float(batch["next", "reward"].mean()),
            "episodes": float(done.sum()),
            "success_rate": float(batch["next", "success"].squeeze(-1)[done].sum()) / ends,
            "drop_rate": float(batch["next", "dropped"].squeeze(-1)[done].sum()) / ends}

