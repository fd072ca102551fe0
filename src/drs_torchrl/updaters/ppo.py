"""PPO as an :class:`~drs_torchrl.updaters.base.Updater`: TorchRL's ``ClipPPOLoss`` with ``GAE`` advantages.

On-policy: each collected batch is trained on for ``epochs`` passes of minibatches and then dropped. With a reward
learner (phase 1), its steps for the batch come first (one per PPO optimisation step, Algorithm 1 lines 9-14);
the learned reward is then computed for the whole batch, before the advantages, and stays fixed over the epochs.
For continuous actions the actor is the same tanh-Gaussian network as SAC's
(:func:`drs_torchrl.models.make_sac_modules`), so ``drs-eval`` reads a PPO ``policy.pt`` like a SAC one; for one-hot
actions (the maze) it is a categorical policy over the same kind of MLP.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule
from torchrl.data import OneHot
from torchrl.modules import MLP, OneHotCategorical, ProbabilisticActor, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from drs_torchrl.models import make_sac_modules
from drs_torchrl.precision import OutputFloat32
from drs_torchrl.updaters.base import LearnerStep, Updater, check_finite

STATS = ("loss_objective", "loss_critic", "loss_entropy", "entropy", "clip_fraction", "kl_approx")


class PPOUpdater(Updater):
    """PPO's updates on each collected batch.

    Args:
        actor: a probabilistic actor that writes its log-probability; critic: a state-value network.
        loss: ``ClipPPOLoss`` over them; advantage: ``GAE`` with the critic.
        optimizer: one optimiser over the loss's parameters.
        epochs, minibatch_size: passes over each batch and transitions per optimisation step.
        reward: a learned reward transform (phase 1), applied to the whole batch before the advantages; None when
            the reward is the env's (static, or frozen in phase 2).
        max_grad_norm: gradient clipping.
    """

    name = "ppo"

    def __init__(
        self,
        actor,
        critic,
        loss: ClipPPOLoss,
        advantage: GAE,
        optimizer: torch.optim.Optimizer,
        *,
        epochs: int,
        minibatch_size: int,
        policy_in_keys,
        hidden,
        reward=None,
        max_grad_norm: float = 0.5,
    ):
        super().__init__()
        self.actor, self.critic, self.loss, self.advantage = actor, critic, loss, advantage
        self.policy = self.eval_policy = actor
        self.optimizer = optimizer
        self.epochs, self.minibatch_size = int(epochs), int(minibatch_size)
        self.policy_in_keys, self.hidden = list(policy_in_keys), list(hidden)
        self.reward, self.max_grad_norm = reward, float(max_grad_norm)
        self._batch: TensorDictBase | None = None

    def extend(self, batch: TensorDictBase) -> None:
        self._batch = batch

    def update(self, frames: int, total_frames: int, learner_step: LearnerStep | None, log) -> int:
        if self._batch is None:
            return 0
        batch, self._batch = self._batch, None
        n = batch.numel()
        per_epoch = max(1, n // self.minibatch_size)
        if learner_step is not None:  # the reward learner first: the reward is then fixed for the epochs
            for _ in range(self.epochs * per_epoch):
                log.learner(learner_step())
        with torch.no_grad():
            if self.reward is not None:
                self.reward(batch)  # writes ("next", "reward") from the current reward modules
            self.advantage(batch)
        rewards = batch.get(("next", "reward")).detach().reshape(-1)
        flat = batch.reshape(-1)
        first = True
        for _ in range(self.epochs):
            for idx in torch.randperm(n, device=flat.device)[: per_epoch * self.minibatch_size].split(
                self.minibatch_size
            ):
                out = self.loss(flat[idx])
                total = out["loss_objective"] + out["loss_critic"] + out.get("loss_entropy", torch.zeros(()))
                check_finite("PPO loss", total.detach())
                self.optimizer.zero_grad(set_to_none=True)
                total.backward()
                torch.nn.utils.clip_grad_norm_(self.loss.parameters(), self.max_grad_norm)
                self.optimizer.step()
                self.updates += 1
                stats = TensorDict({k: out.get(k).detach().float().mean() for k in STATS if k in out.keys()}, [])
                log.update(stats, rewards if first else None)  # the batch's rewards, logged once
                first = False
        return self.epochs * per_epoch

    def state_dict(self) -> dict[str, Any]:
        return {
            "loss": self.loss.state_dict(),
            "optimizers": {"ppo": self.optimizer.state_dict()},
            "updates": self.updates,
            "owed_updates": 0.0,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.loss.load_state_dict(state["loss"])
        self.optimizer.load_state_dict(state["optimizers"]["ppo"])
        self.updates = int(state["updates"])

    def policy_checkpoint(self) -> dict[str, Any]:
        return {"policy_in_keys": self.policy_in_keys, "hidden": self.hidden, "actor": self.actor.state_dict()}


def categorical_actor(n_in: int, action_spec, in_keys, hidden) -> ProbabilisticActor:
    """A categorical policy over one-hot actions: an MLP's logits, sampled while collecting, argmax when evaluated."""
    mlp = MLP(in_features=n_in, out_features=int(action_spec.shape[-1]), num_cells=list(hidden))
    mlp.append(OutputFloat32())
    return ProbabilisticActor(
        TensorDictModule(mlp, in_keys=list(in_keys), out_keys=["logits"]),
        in_keys=["logits"],
        spec=action_spec,
        distribution_class=OneHotCategorical,
        return_log_prob=True,
        default_interaction_type="random",
    )


def make_ppo_updater(
    env,
    replay=None,
    *,
    optim: Callable,
    hidden,
    policy_in_keys,
    gamma: float,
    lmbda: float,
    epochs: int,
    minibatch_size: int,
    clip_epsilon: float = 0.2,
    entropy_coeff: float = 0.0,
    critic_coeff: float = 0.5,
    max_grad_norm: float = 0.5,
    normalize_advantage: bool = True,
    device: torch.device | str = "cpu",
    reward=None,
    precision: str = "fp32",
    grad_scaler=None,
    demo_replay=None,
    demo_batch: int = 0,
) -> PPOUpdater:
    """A :class:`PPOUpdater` for ``env``'s specs. The arguments the run passes every updater that PPO does not use
    are named, so that a misspelt setting of its ``updater`` node fails: ``replay`` (on-policy), ``precision`` and
    ``grad_scaler`` (PPO runs fp32: its small networks gain nothing from autocast), ``demo_replay`` / ``demo_batch``
    (it trains on its own batches; demonstrations still reach the stage buffers)."""
    del replay, precision, grad_scaler, demo_replay, demo_batch  # not used, see above
    keys = list(policy_in_keys)
    n_in = sum(int(env.observation_spec[k].shape[-1]) for k in keys)
    if isinstance(env.action_spec, OneHot):
        actor = categorical_actor(n_in, env.action_spec, keys, list(hidden)).to(device)
    else:
        actor, _ = make_sac_modules(
            env.observation_spec, env.action_spec, keys, list(hidden), device=device, return_log_prob=True
        )
    value_mlp = MLP(in_features=n_in, out_features=1, num_cells=list(hidden), activation_class=torch.nn.ReLU)
    value_mlp.append(OutputFloat32())
    critic = ValueOperator(value_mlp, in_keys=keys).to(device)
    loss = ClipPPOLoss(
        actor,
        critic,
        clip_epsilon=float(clip_epsilon),
        entropy_bonus=float(entropy_coeff) > 0,
        entropy_coeff=float(entropy_coeff) if float(entropy_coeff) > 0 else None,
        critic_coeff=float(critic_coeff),
        loss_critic_type="l2",
        normalize_advantage=bool(normalize_advantage),
    )
    advantage = GAE(gamma=float(gamma), lmbda=float(lmbda), value_network=critic, average_gae=False)
    return PPOUpdater(
        actor,
        critic,
        loss,
        advantage,
        optim(loss.parameters()),
        epochs=epochs,
        minibatch_size=minibatch_size,
        policy_in_keys=keys,
        hidden=hidden,
        reward=reward,
        max_grad_norm=max_grad_norm,
    )
