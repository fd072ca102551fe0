"""SAC (Sec. 5, Appendix E) as an :class:`~drs_torchrl.updaters.base.Updater`: TorchRL's ``SACLoss``, its target
updater and optimisers, and a replay buffer whose sampling transform recomputes a learned reward (Algorithm 1,
line 18); with demonstrations, a share of every batch comes from them (:mod:`drs_torchrl.data.demo_mix`)."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import ReplayBuffer

from drs_torchrl.models import POLICY_INTERMEDIATE_KEYS, make_sac_modules
from drs_torchrl.precision import autocast
from drs_torchrl.updaters.base import LearnerStep, UpdateBudget, Updater, backward_and_step, check_finite


class SACUpdater(Updater):
    """SAC's updates at ``utd`` per env step once ``learning_starts`` env steps are in and the buffer holds a batch.

    Args:
        actor, qvalue: the tanh-Gaussian actor and a Q-network template (:func:`drs_torchrl.models.make_sac_modules`).
        loss: TorchRL's ``SACLoss`` over them (value estimator made); target_updater: its ``SoftUpdate``.
        optimizers: ``{"actor", "critic", "alpha"}``.
        replay: the agent's replay buffer (its transform recomputes a learned reward at sampling).
        utd: updates per env step; learning_starts: env steps before the first update.
        demo_replay, demo_batch: the demonstrations' buffer and their transitions per batch (or None, 0).
        precision, device, grad_scaler: autocast of the forward passes (:mod:`drs_torchrl.precision`).
        compile: None, ``"loss"`` (``torch.compile`` the loss's forward) or ``"update"`` (loss, backward, optimiser
            steps and target update as one compiled function, as TorchRL's ``sota-implementations/sac``), with
            ``compile_kwargs``; see :data:`COMPILE_SCOPES`.
    """

    name = "sac"

    def __init__(
        self,
        actor,
        qvalue,
        loss,
        target_updater,
        optimizers: dict[str, torch.optim.Optimizer],
        replay: ReplayBuffer,
        *,
        utd: float,
        learning_starts: int,
        policy_in_keys,
        hidden,
        demo_replay: ReplayBuffer | None = None,
        demo_batch: int = 0,
        precision: str = "fp32",
        device: torch.device | str = "cpu",
        grad_scaler=None,
        compile: str | None = None,
        compile_kwargs: dict | None = None,
        critic_norm: str | None = None,
        actor_norm: str | None = None,
        policy_delay: int = 1,
    ):
        super().__init__()
        self.critic_norm, self.actor_norm = critic_norm, actor_norm
        self.policy_delay = int(policy_delay)
        if self.policy_delay < 1:
            raise ValueError(f"algo.policy_delay must be >= 1, got {policy_delay}")
        # batch-normalised networks learn on batch statistics and act on running ones (CrossQ)
        self._batch_stats = "batch_renorm" in (critic_norm, actor_norm)
        self.actor, self.qvalue, self.loss, self.target_updater = actor, qvalue, loss, target_updater
        self.policy = self.eval_policy = actor
        self.optimizers = optimizers
        self.replay, self.demo_replay, self.demo_batch = replay, demo_replay, int(demo_batch)
        self.budget = UpdateBudget(utd)
        self.learning_starts = int(learning_starts)
        self.policy_in_keys, self.hidden = list(policy_in_keys), list(hidden)
        self.precision, self.device, self.grad_scaler = precision, torch.device(device), grad_scaler
        self.compile_scope = compile_scope(compile)
        if self.compile_scope == "update" and grad_scaler is not None:
            raise ValueError("algo.compile=update does not take fp16's gradient scaler: use bf16 or fp32")
        kw = dict(compile_kwargs or {})
        self._loss_fn = torch.compile(loss, **kw) if self.compile_scope == "loss" else loss
        self._learn_fn = torch.compile(self._learn, **kw) if self.compile_scope == "update" else self._learn
        # the actor's intermediate outputs and the collector's bookkeeping are not stored: SACLoss recomputes the
        # former, nothing reads the latter, and every extra key costs at each sample
        self._exclude: tuple | None = None

    @property
    def buffers(self) -> dict[str, ReplayBuffer]:
        return {"replay": self.replay}

    def extend(self, batch: TensorDictBase) -> None:
        if self._exclude is None:  # a resumed buffer started with every key keeps them
            stored = self.replay.storage._storage if len(self.replay) else None
            kept = stored is not None and any(k in stored.keys() for k in (*POLICY_INTERMEDIATE_KEYS, "collector"))
            self._exclude = () if kept else (*POLICY_INTERMEDIATE_KEYS, "collector")
        self.replay.extend(batch.exclude(*self._exclude).reshape(-1))

    def sample(self) -> TensorDict:
        """One SAC batch from the replay buffer (and the demonstrations' share), rewards recomputed."""
        if self.demo_replay is None:
            return self.replay.sample().to(self.device)
        demo = self.demo_replay.sample(self.demo_batch)
        agent = self.replay.sample().to(self.device).select(*demo.keys(True, True))
        return torch.cat([agent, demo.to(self.device)], 0)

    def update(self, frames: int, total_frames: int, learner_step: LearnerStep | None, log) -> int:
        if total_frames < self.learning_starts or len(self.replay) < self.replay.batch_size:
            return 0
        n_updates = self.budget.take(frames)
        for _ in range(n_updates):
            if learner_step is not None:
                log.learner(learner_step())
            stats, reward = self.step()
            log.update(stats, reward)
        return n_updates

    def step(self) -> tuple[TensorDict, torch.Tensor]:
        """One SAC update on a fresh batch; returns its statistics and the rewards it trained on."""
        sample = self.sample()  # the learned reward is recomputed here, in fp32
        # the loss's networks are not its registered children (TorchRL keeps their parameters apart): set their modes
        nets = (self.loss.actor_network, self.loss.qvalue_network) if self._batch_stats else ()
        for net in nets:
            net.train()
        try:
            # the actor and alpha learn every policy_delay-th update (TD3, CrossQ), the critics every update
            stats, total = self._learn_fn(sample, self.updates % self.policy_delay == 0)
        finally:
            for net in nets:
                net.eval()
        if self.compile_scope == "update":
            # eager, the loss is checked before the step; compiled whole, after it: nothing is lost, as the run then
            # stops without saving and its last checkpoint stays as it was
            check_finite("SAC loss", total)
        self.updates += 1
        return stats, sample.get(("next", "reward")).detach()

    def _learn(self, sample: TensorDictBase, policy_step: bool) -> tuple[TensorDict, torch.Tensor]:
        """Loss, backward, optimiser steps and target update on ``sample``: the part ``algo.compile=update``
        compiles as one function (one graph per value of ``policy_step``)."""
        with autocast(self.precision, self.device):
            out = self._loss_fn(sample)
        total = out["loss_qvalue"] + (out["loss_actor"] + out["loss_alpha"] if policy_step else 0.0)
        if self.compile_scope != "update":
            check_finite("SAC loss", total.detach())
        opts = list(self.optimizers.values()) if policy_step else [self.optimizers["critic"]]
        for opt in self.optimizers.values():
            opt.zero_grad(set_to_none=True)
        backward_and_step(self.grad_scaler, total, opts)
        if self.target_updater is not None:  # CrossQ has no target networks
            self.target_updater.step()
        return out.detach().select("loss_actor", "loss_qvalue", "loss_alpha", "alpha", "entropy"), total.detach()

    def state_dict(self) -> dict[str, Any]:
        return {
            "loss": self.loss.state_dict(),
            "optimizers": {k: o.state_dict() for k, o in self.optimizers.items()},
            "updates": self.updates,
            "owed_updates": self.budget.owed,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.loss.load_state_dict(state["loss"])
        for k, sd in state["optimizers"].items():
            if k in self.optimizers:
                self.optimizers[k].load_state_dict(sd)
        self.updates, self.budget.owed = int(state["updates"]), float(state["owed_updates"])

    def policy_checkpoint(self) -> dict[str, Any]:
        return {
            "policy_in_keys": self.policy_in_keys,
            "hidden": self.hidden,
            "actor_norm": self.actor_norm,
            "critic_norm": self.critic_norm,
            "actor": self.actor.state_dict(),
            # SACLoss trains its own stacked copies of the critics (one per Q-net), not self.qvalue
            "qvalue_params": self.loss.qvalue_network_params.data.cpu().to_dict(),
            "num_qvalue_nets": int(self.loss.num_qvalue_nets),
            "log_alpha": self.loss.log_alpha.detach().cpu(),
        }

    def init_from(self, ck: dict) -> list[str]:
        """Start from a policy checkpoint's actor, twin critics (and their targets) and entropy coefficient
        (fine-tuning, Sec. 5.4.2); returns what does not fit (empty when it loaded)."""
        problems = []
        if list(ck["policy_in_keys"]) != self.policy_in_keys or list(ck["hidden"]) != self.hidden:
            problems.append(
                f"its networks read {ck['policy_in_keys']} with hidden {ck['hidden']}, this run's read "
                f"{self.policy_in_keys} with hidden {self.hidden}"
            )
        norms = (ck.get("actor_norm"), ck.get("critic_norm"))
        if norms != (self.actor_norm, self.critic_norm):
            problems.append(
                f"its actor and critics are normalised {norms}, this run's {(self.actor_norm, self.critic_norm)} "
                "(algo.actor_norm / algo.critic_norm)"
            )
        if "qvalue_params" not in ck:
            problems.append("it holds no critics")
        if problems:
            return problems
        try:
            self.actor.load_state_dict(ck["actor"])
            q = TensorDict(ck["qvalue_params"]).to(self.device)
            self.loss.qvalue_network_params.data.update_(q)
            if getattr(self.loss, "target_qvalue_network_params", None) is not None:
                self.loss.target_qvalue_network_params.data.update_(q)
            if "log_alpha" in ck:
                self.loss.log_alpha.data.copy_(torch.as_tensor(ck["log_alpha"]))
        except (RuntimeError, KeyError) as exc:
            return [f"its sizes do not fit this env: {str(exc).splitlines()[0]}"]
        return []


COMPILE_SCOPES = {
    "loss": "torch.compile of the loss's forward (backward and optimiser steps eager)",
    "update": "loss, backward, optimiser steps and target update compiled as one function (fp32; the twin critics "
    "in one vmap, Adam unfused)",
}


def compile_scope(value) -> str | None:
    """``algo.compile`` as a scope: false/None -> None, true -> ``"loss"`` (what ``true`` always meant), or a key of
    :data:`COMPILE_SCOPES`."""
    if value is None or value is False:
        return None
    if value is True:
        return "loss"
    if isinstance(value, str) and value.lower() in COMPILE_SCOPES:
        return value.lower()
    raise ValueError(
        f"algo.compile must be false, true (= loss), loss or update, got {value!r}; "
        + "; ".join(f"{k}: {v}" for k, v in COMPILE_SCOPES.items())
    )


def _unfused(optim: Callable) -> Callable:
    """``optim`` (a partial of a torch optimiser) without ``fused=True``."""
    kw = getattr(optim, "keywords", None)
    if not kw or not kw.get("fused"):
        return optim
    return functools.partial(optim.func, *optim.args, **{**kw, "fused": False})


def make_sac_updater(
    env,
    replay: ReplayBuffer,
    *,
    loss: Callable,
    optim: Callable,
    target_update: Callable | None,
    hidden,
    policy_in_keys,
    gamma: float,
    utd: float,
    learning_starts: int,
    device: torch.device | str = "cpu",
    precision: str = "fp32",
    grad_scaler=None,
    reward=None,
    demo_replay: ReplayBuffer | None = None,
    demo_batch: int = 0,
    compile: bool | str = False,
    compile_kwargs: dict | None = None,
    critic_norm: str | None = None,
    actor_norm: str | None = None,
    policy_delay: int = 1,
) -> SACUpdater:
    """A :class:`SACUpdater` for ``env``'s specs from the ``algo`` config's partials (``loss``: ``SACLoss``,
    ``optim``, ``target_update``) over ``replay`` (its transform: the learned ``reward``, recomputed at sampling;
    ``reward`` is checked to be that transform);
    ``demo_replay`` / ``demo_batch``: the demonstrations' share of each batch; ``critic_norm`` / ``actor_norm``:
    :func:`~drs_torchrl.models.make_sac_modules`' normalisation (``loss`` may be another of TorchRL's SAC-family
    losses taking the same networks: ``REDQLoss``, an ensemble of critics; ``CrossQLoss`` with ``target_update=None``
    and batch-renormalised networks); ``policy_delay``: the actor and alpha learn every k-th update."""
    if reward is not None and replay is not None and not any(t is reward for t in getattr(replay, "_transform", [])):
        # SAC trains on the rewards its replay buffer's transform recomputes at sampling (Algorithm 1, line 18)
        raise ValueError("the learned reward must be the replay buffer's transform (make_replay_buffer(transform=...))")
    actor, qvalue = make_sac_modules(
        env.observation_spec, env.action_spec, list(policy_in_keys), list(hidden), device=device,
        critic_norm=critic_norm, actor_norm=actor_norm,
    )  # fmt: skip
    kwargs = {}
    if compile_scope(compile) == "update":
        # compiled whole, the twin critics run in one vmap: one after the other, TorchRL's functional calls change
        # a pytree registry that the compiled graph's guards read, and it recompiles at every update
        if precision != "fp32":
            raise ValueError(
                f"algo.compile=update runs the critics in one torch.vmap, which autocast does not reach: use "
                f"algo.precision=fp32 with it (got {precision}), or algo.compile=loss"
            )
        kwargs["deactivate_vmap"] = False
        # the fused Adam kernel is not traced (a graph break each step): the compiled graph holds the plain one
        optim = _unfused(optim)
    elif precision != "fp32":
        # torch.autocast does not reach inside torch.vmap (the twin critics' batched pass would stay fp32):
        # in low precision the critics are evaluated one after the other, whatever algo.loss says
        kwargs["deactivate_vmap"] = True
    sac_loss = loss(actor_network=actor, qvalue_network=qvalue, action_spec=env.action_spec, **kwargs).to(device)
    sac_loss.make_value_estimator(gamma=float(gamma))
    optimizers = {
        "actor": optim(list(sac_loss.actor_network_params.values(True, True))),
        "critic": optim(list(sac_loss.qvalue_network_params.values(True, True))),
        "alpha": optim([sac_loss.log_alpha]),
    }
    return SACUpdater(
        actor,
        qvalue,
        sac_loss,
        target_update(sac_loss) if target_update is not None else None,
        optimizers,
        replay,
        utd=utd,
        learning_starts=learning_starts,
        policy_in_keys=policy_in_keys,
        hidden=hidden,
        demo_replay=demo_replay,
        demo_batch=demo_batch,
        precision=precision,
        device=device,
        grad_scaler=grad_scaler,
        compile=compile,
        compile_kwargs=compile_kwargs,
        critic_norm=critic_norm,
        actor_norm=actor_norm,
        policy_delay=policy_delay,
    )
