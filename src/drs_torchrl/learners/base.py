"""The reward-learning core: what Algorithm 1 adds to an RL loop, apart from any RL algorithm.

An RL loop (SAC, DQN for the maze, PPO: :mod:`drs_torchrl.updaters`) talks to a :class:`RewardLearner` through a few
calls: it hands over what it collected (:meth:`~RewardLearner.observe`), lets it take its update
steps (:meth:`~RewardLearner.update`, once per RL update) and saves it (:meth:`~RewardLearner.save_reward`,
:meth:`~RewardLearner.state_dict`, :meth:`~RewardLearner.dump_buffers`). Its :attr:`~RewardLearner.reward`
is a TorchRL ``Transform``; the loop puts it on its replay buffer, so rewards are recomputed from
the current reward modules whenever the RL algorithm samples (Algorithm 1, line 18).

Static rewards (sparse, semi-sparse, dense) need no learner: they are transforms of the env.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.envs.transforms import Transform


def plain_step(loss: torch.Tensor, optimizers: Sequence[torch.optim.Optimizer]) -> None:
    """Backward pass and optimiser steps (the default ``step_fn`` of a learner)."""
    loss.backward()
    for opt in optimizers:
        opt.step()


class RewardLearner:
    """Base class of the learned rewards (DrS, VICE-RAQ, ORIL, GAIL).

    Subclasses set :attr:`name` and :attr:`reward` and implement what they need of the calls below;
    the defaults do nothing, so a learner that trains offline (ORIL) only overrides :meth:`prepare`.

    Args:
        device: where the reward modules live.
        autocast: a context-manager factory for the reward's forward passes (``algo.precision``).
        step_fn: ``step_fn(loss, optimizers)`` runs backward and the steps (e.g. through a gradient scaler).
    """

    name = "learned"
    reward: Transform
    # True where the training state holds the demonstrations (DrS files them into its stage buffers, which are saved):
    # a resumed run then does not read them again
    stage_buffers_hold_demos = False

    def __init__(
        self,
        *,
        device: torch.device | str = "cpu",
        autocast: Callable[[], Any] | None = None,
        step_fn: Callable[[torch.Tensor, Sequence[torch.optim.Optimizer]], None] = plain_step,
    ):
        self.device = torch.device(device)
        self._autocast = autocast or contextlib.nullcontext
        self._step_fn = step_fn
        self.updates = 0
        self.reward_updates_per_update = 1.0
        self._owed_steps = 0.0

    # ------------------------------------------------------------------ the loop's calls
    def prepare(self, env) -> None:
        """Called once before the first env step of a fresh run, with the training env."""

    def attach(self, replay) -> None:
        """The RL algorithm's replay buffer (GAIL draws the agent's transitions from it)."""

    def observe(self, batch: TensorDictBase, episodes: list[TensorDictBase]) -> None:
        """A collected batch of transitions and the episodes that finished in it."""

    def update(self) -> TensorDict | None:
        """The learner's own training for one RL update; returns statistics to log, or None."""
        return None

    def log_row(self) -> dict[str, float]:
        """Gauges to log with the training row (buffer sizes, rates)."""
        return {}

    def summary(self) -> dict[str, Any]:
        """What ``summary.json`` records about the learner at the end of a run."""
        return {}

    # ------------------------------------------------------------------ persistence
    def save_reward(self, path: str | Path, **metadata) -> Path:
        """The reusable reward checkpoint (``reward.pt``)."""
        return self.reward.save(path, **metadata)

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        return {}

    def state_dict(self) -> dict[str, Any]:
        return {
            "reward": self.reward.state_dict(),
            "updates": self.updates,
            "owed_steps": self._owed_steps,
            "optimizers": {k: o.state_dict() for k, o in self.optimizers().items()},
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.reward.load_state_dict(state["reward"])
        self.updates = int(state.get("updates", 0))
        self._owed_steps = float(state.get("owed_steps", 0.0))
        for k, opt in self.optimizers().items():
            if k in (state.get("optimizers") or {}):
                opt.load_state_dict(state["optimizers"][k])

    def dump_buffers(self, directory: Path) -> None:
        """Write the learner's data (stage buffers, classifier data) under ``directory``."""

    def load_buffers(self, directory: Path) -> None:
        """Read what :meth:`dump_buffers` wrote."""

    # ------------------------------------------------------------------ helpers
    def _set_reward_updates_per_update(self, value: float) -> None:
        value = float(value)
        if not value > 0:
            raise ValueError(f"reward-learner steps per RL update must be > 0, got {value}")
        self.reward_updates_per_update = value

    def _steps_due(self) -> int:
        """The learner's steps for this RL update. ``reward_updates_per_update`` may be fractional (0.5: one
        step every second RL update; 1.5: one and two in turn); the remainder carries to the next call."""
        self._owed_steps += self.reward_updates_per_update
        due = int(self._owed_steps + 1e-9)
        self._owed_steps -= due
        return due

    def _train_step(self, loss: torch.Tensor, optimizers: Sequence[torch.optim.Optimizer]) -> None:
        for opt in optimizers:
            opt.zero_grad(set_to_none=True)
        self._step_fn(loss, optimizers)
        self.updates += 1
