"""What the loop of Algorithm 1 asks of an RL algorithm: an :class:`Updater`.

The loop (:func:`drs_torchrl.loop.run_algorithm1`) collects, files finished episodes, and hands each batch to the
updater (:meth:`Updater.extend`), then asks it for the updates the new env steps pay for
(:meth:`Updater.update`); the updater calls ``learner_step`` (the reward learner's update, Algorithm 1 lines
9-14) where its algorithm takes an optimisation step. An off-policy updater (SAC, DQN) keeps a replay buffer whose
sampling transform recomputes a learned reward; an on-policy one (PPO) rewards its whole batch before its
advantages. Everything else (checkpoints, logging, evaluation, signals) is the loop's.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import ReplayBuffer

LearnerStep = Callable[[], "TensorDict | None"]


class NonFiniteError(RuntimeError):
    """NaN or inf in observations, rewards or losses (the loop adds where: env step, update, checkpoint)."""


def check_finite(what: str, value: torch.Tensor) -> None:
    if not bool(torch.isfinite(value).all()):
        raise NonFiniteError(f"non-finite {what}")


def backward_and_step(grad_scaler, loss: torch.Tensor, optimizers: Sequence[torch.optim.Optimizer]) -> None:
    """Backward pass and optimiser steps, through an fp16 gradient scaler when there is one."""
    if grad_scaler is None:
        loss.backward()
        for opt in optimizers:
            opt.step()
        return
    grad_scaler.scale(loss).backward()
    for opt in optimizers:
        grad_scaler.step(opt)
    grad_scaler.update()


class UpdateBudget:
    """Updates owed for env steps at a fractional ratio (UTD 0.5, 1/3, 0.25): the remainder carries over."""

    def __init__(self, per_frame: float):
        if not per_frame > 0:
            raise ValueError(f"updates per env step must be > 0, got {per_frame}")
        self.per_frame = float(per_frame)
        self.owed = 0.0

    def take(self, frames: int) -> int:
        self.owed += frames * self.per_frame
        due = int(self.owed + 1e-9)  # 1/3 x 192 sums to 63.99999999: the update owed at an exact boundary is due
        self.owed = max(self.owed - due, 0.0)
        return due


class Updater:
    """One RL algorithm's part of Algorithm 1 (SAC, DQN, PPO: :mod:`drs_torchrl.updaters`).

    Attributes the loop reads: :attr:`policy` (what collects, exploration included), :attr:`eval_policy` (what
    evaluation runs, deterministically), :attr:`updates` (optimisation steps so far), :attr:`learning_starts`
    (env steps of random actions before the first update), :attr:`buffers` (replay buffers saved with the
    training state).
    """

    name = "updater"
    policy: Any
    eval_policy: Any
    learning_starts: int = 0

    def __init__(self):
        self.updates = 0

    @property
    def buffers(self) -> dict[str, ReplayBuffer]:
        return {}

    def extend(self, batch: TensorDictBase) -> None:
        """A collected batch (the updater stores what it needs)."""
        raise NotImplementedError

    def update(self, frames: int, total_frames: int, learner_step: LearnerStep | None, log) -> int:
        """The updates owed for the ``frames`` env steps just stored (``total_frames`` so far), calling
        ``learner_step`` where the reward learner's steps belong; each update's statistics and the rewards it
        trained on go to ``log.update(stats, rewards)``, the learner's to ``log.learner(stats)``. Returns the
        number of updates taken."""
        raise NotImplementedError

    def after_collect(self, frames: int) -> None:
        """Called after every batch (e.g. epsilon annealing)."""

    def state_dict(self) -> dict[str, Any]:
        """Networks, target networks, optimisers, counters (``loss``, ``optimizers``, ``updates``, ``owed_updates``)."""
        raise NotImplementedError

    def load_state_dict(self, state: dict[str, Any]) -> None:
        raise NotImplementedError

    def policy_checkpoint(self) -> dict[str, Any]:
        """What ``checkpoints/policy.pt`` holds besides the run's metadata."""
        raise NotImplementedError
