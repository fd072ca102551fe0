"""DQN (the maze, Appendix "Navigation") as an :class:`~drs_torchrl.updaters.base.Updater`: TorchRL's ``DQNLoss``
(double DQN), a target updater, epsilon-greedy exploration, and a replay buffer of single steps (a learned reward
recomputed at sampling) or of n-step windows (TorchRL's ``MultiStepTransform``: the reward is then the one written
when the step was taken)."""

from __future__ import annotations

from typing import Any, Callable

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictSequential
from torchrl.data import ReplayBuffer
from torchrl.modules import MLP, EGreedyModule, QValueActor
from torchrl.objectives import DQNLoss, ValueEstimators

from drs_torchrl.updaters.base import LearnerStep, UpdateBudget, Updater, check_finite

# the entries a DQN transition needs (what the replay buffer stores)
TRANSITION_KEYS = [
    "observation",
    "action",
    ("next", "observation"),
    ("next", "reward"),
    ("next", "done"),
    ("next", "terminated"),
    ("next", "truncated"),
    ("next", "stage"),
]
# n-step targets: whether the observation a window ends on is terminal (see terminal_at_window_end)
TERMINAL_AT_OBS = ("next", "terminal_obs")


def mark_terminal_obs(batch: TensorDictBase) -> TensorDictBase:
    """Copy ``("next", "terminated")`` to :data:`TERMINAL_AT_OBS` before n-step windows are formed.

    TorchRL 0.14's ``MultiStepTransform`` cuts a window at the episode's end and gathers the ``"next"`` entries of
    the window's last step, *except* the done keys, which stay those of the window's first step. A window that
    reaches the goal a few steps ahead therefore ends on the terminal observation with ``terminated=False``, and
    the TD target bootstraps from the value of a state that has none. A copy under another name is gathered with
    the observation, so it says whether the observation the window ends on is terminal.
    """
    batch.set(TERMINAL_AT_OBS, batch.get(("next", "terminated")).clone())
    return batch


def terminal_at_window_end(sample: TensorDictBase) -> TensorDictBase:
    """Set ``("next", "terminated")`` (and ``"done"``) of sampled n-step windows from :data:`TERMINAL_AT_OBS`."""
    term = sample.get(TERMINAL_AT_OBS)
    sample.set(("next", "terminated"), term)
    sample.set(("next", "done"), sample.get(("next", "done")) | term)
    return sample


class DQNUpdater(Updater):
    """DQN's updates at ``utd`` per env step once ``learning_starts`` env steps are in.

    Args:
        actor: a ``QValueActor``; explore: its ``EGreedyModule`` (annealed per collected env step).
        loss: TorchRL's ``DQNLoss`` (value estimator made); target_updater: ``HardUpdate`` / ``SoftUpdate``.
        optimizer: over the loss's parameters; grad_clip: the gradient norm's bound.
        replay: single steps, or n-step windows over a ``(envs, T)`` storage with ``n_step=True``.
        learner_after: the reward learner's step follows each DQN step (the order every committed maze run used).
    """

    name = "dqn"

    def __init__(
        self,
        actor,
        explore,
        loss,
        target_updater,
        optimizer: torch.optim.Optimizer,
        replay: ReplayBuffer,
        *,
        utd: float,
        learning_starts: int,
        grad_clip: float = 10.0,
        n_step: bool = False,
        learner_after: bool = True,
    ):
        super().__init__()
        self.actor, self.explore, self.loss, self.target_updater = actor, explore, loss, target_updater
        self.policy, self.eval_policy = TensorDictSequential(actor, explore), actor
        self.optimizer, self.replay = optimizer, replay
        self.budget, self.learning_starts = UpdateBudget(utd), int(learning_starts)
        self.grad_clip, self.n_step, self.learner_after = float(grad_clip), bool(n_step), bool(learner_after)

    @property
    def buffers(self) -> dict[str, ReplayBuffer]:
        return {"replay": self.replay}

    def extend(self, batch: TensorDictBase) -> None:
        if self.n_step:  # windows are formed over the (envs, T) layout of the batch
            self.replay.extend(mark_terminal_obs(batch.select(*TRANSITION_KEYS)))
        else:
            self.replay.extend(batch.reshape(-1).select(*TRANSITION_KEYS))

    def after_collect(self, frames: int) -> None:
        self.explore.step(frames)

    def update(self, frames: int, total_frames: int, learner_step: LearnerStep | None, log) -> int:
        if total_frames < self.learning_starts:
            return 0
        n_updates = self.budget.take(frames)
        for _ in range(n_updates):
            if learner_step is not None and not self.learner_after:
                log.learner(learner_step())
            stats, rewards = self.step()
            log.update(stats, rewards)
            if learner_step is not None and self.learner_after:
                log.learner(learner_step())
        return n_updates

    def step(self) -> tuple[TensorDict, torch.Tensor]:
        """One DQN update on a fresh batch; returns its statistics and the (one-step) rewards it trained on."""
        sample = self.replay.sample()
        out = self.loss(terminal_at_window_end(sample) if self.n_step else sample)
        check_finite("DQN loss", out["loss"].detach())
        self.optimizer.zero_grad(set_to_none=True)
        out["loss"].backward()
        torch.nn.utils.clip_grad_norm_(self.loss.parameters(), self.grad_clip)
        self.optimizer.step()
        self.target_updater.step()
        self.updates += 1
        one_step = sample.get(("next", "original_reward"), None)  # n-step windows keep the one-step reward here
        rewards = one_step if one_step is not None else sample.get(("next", "reward"))
        return TensorDict({"dqn_loss": out["loss"].detach()}, []), rewards.detach()

    def state_dict(self) -> dict[str, Any]:
        """The agent's state. Not the n-step windows the replay buffer's transform holds back at a batch's end: they
        belong to the episodes in flight, which a resumed run does not continue (it starts fresh ones)."""
        return {
            "loss": self.loss.state_dict(),
            "optimizers": {"dqn": self.optimizer.state_dict()},
            "explore": self.explore.state_dict(),
            "target": self.target_updater.state_dict(),  # its counter: when the next hard copy comes
            "updates": self.updates,
            "owed_updates": self.budget.owed,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.loss.load_state_dict(state["loss"])
        self.optimizer.load_state_dict(state["optimizers"]["dqn"])
        self.explore.load_state_dict(state["explore"])
        self.target_updater.load_state_dict(state["target"])
        self.updates, self.budget.owed = int(state["updates"]), float(state["owed_updates"])

    def policy_checkpoint(self) -> dict[str, Any]:
        return {"qnet": self.actor.state_dict()}


def q_network(env, hidden) -> QValueActor:
    """The Q-network: a ``QValueActor`` over an MLP (ReLU) from ``"observation"`` to one value per action of ``env``'s
    one-hot action spec (what ``policy.pt`` of a maze run holds)."""
    net = MLP(
        in_features=int(env.observation_spec["observation"].shape[-1]),
        out_features=int(env.action_spec.shape[-1]),
        num_cells=list(hidden),
        activation_class=torch.nn.ReLU,
    )
    return QValueActor(net, in_keys=["observation"], spec=env.action_spec)


def make_dqn_updater(
    env,
    replay: ReplayBuffer,
    *,
    optim: Callable,
    hidden,
    gamma: float,
    target_update: Callable,
    eps_init: float,
    eps_end: float,
    eps_anneal_steps: int,
    utd: float,
    learning_starts: int,
    double_dqn: bool = True,
    loss_function: str = "l2",
    grad_clip: float = 10.0,
    n_step: bool = False,
) -> DQNUpdater:
    """A :class:`DQNUpdater` for ``env``'s specs (a one-hot action): the :func:`q_network`, TorchRL's ``DQNLoss``
    with a TD(0) estimator (double DQN by default), ``target_update(loss)`` (``HardUpdate`` / ``SoftUpdate``),
    ``optim(parameters)`` and epsilon-greedy annealed over ``eps_anneal_steps`` env steps. ``replay`` holds single
    steps, or n-step windows with ``n_step=True``."""
    actor = q_network(env, hidden)
    loss = DQNLoss(
        actor, action_space=env.action_spec, delay_value=True, double_dqn=bool(double_dqn), loss_function=loss_function
    )
    loss.make_value_estimator(ValueEstimators.TD0, gamma=float(gamma))
    target, optimizer = target_update(loss), optim(loss.parameters())
    explore = EGreedyModule(
        env.action_spec,
        eps_init=float(eps_init),
        eps_end=float(eps_end),
        annealing_num_steps=max(1, int(eps_anneal_steps)),
    )
    return DQNUpdater(
        actor, explore, loss, target, optimizer, replay,
        utd=float(utd), learning_starts=int(learning_starts), grad_clip=float(grad_clip), n_step=bool(n_step),
    )  # fmt: skip
