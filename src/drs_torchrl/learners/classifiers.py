"""The paper's classifier baselines of reward learning (Sec. 5.2, Appendix F.2), on the same core as DrS.

* :class:`SuccessClassifierLearner` (``vice_raq``): success states (the oracle's success indicator,
  queried for every state the agent visits, as the paper grants it) vs every other visited state,
  trained online alongside the RL agent.
* :class:`OfflineClassifierLearner` (``oril``): demonstration states vs states of random-policy
  trajectories, trained once before RL and then frozen (the agent's interaction teaches it nothing).
* :class:`DemoDiscriminatorLearner` (``gail``): demonstrations vs the agent's own transitions, drawn
  from the RL replay buffer (off-policy GAIL, as DAC), with TorchRL's :class:`~torchrl.objectives.GAILLoss`.

Each trains the one classifier of a :class:`~drs_torchrl.transforms.ClassifierReward` in place.
"""

from __future__ import annotations

from pathlib import Path

import torch
import torch.nn.functional as F
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.objectives import GAILLoss

from drs_torchrl.data.persistence import dump_buffer, load_buffer
from drs_torchrl.learners.base import RewardLearner
from drs_torchrl.transforms.classifier_reward import ClassifierReward


def _bce_step_stats(logits: torch.Tensor, labels: torch.Tensor) -> tuple[torch.Tensor, TensorDict]:
    logits = logits.float().reshape(-1)
    loss = F.binary_cross_entropy_with_logits(logits, labels)
    with torch.no_grad():
        acc = ((logits > 0).float() == labels).float().mean()
    return loss, TensorDict({"loss": loss.detach(), "accuracy": acc}, batch_size=[])


def _buffer(capacity: int) -> ReplayBuffer:
    return ReplayBuffer(storage=LazyTensorStorage(int(capacity)))


class _TwoSetClassifier(RewardLearner):
    """A classifier of positives vs negatives held in two TorchRL replay buffers."""

    def __init__(
        self,
        reward: ClassifierReward,
        *,
        capacity: int = 1_000_000,
        batch_size: int = 256,
        lr: float = 3e-4,
        fused: bool = False,
        reward_updates_per_update: float = 1,
        **kw,
    ):
        super().__init__(**kw)
        self.reward = reward
        self.batch_size = int(batch_size)
        self._set_reward_updates_per_update(reward_updates_per_update)
        self.positives, self.negatives = _buffer(capacity), _buffer(capacity)
        self.optim = torch.optim.Adam(reward.classifier.parameters(), lr=float(lr), fused=bool(fused))

    def _states(self, td: TensorDictBase) -> TensorDictBase:
        return td.select(*self.reward.reward_in_keys).reshape(-1).clone()

    def _step(self) -> TensorDict | None:
        if len(self.positives) == 0 or len(self.negatives) == 0:
            return None
        B = self.batch_size
        data = torch.cat([self.positives.sample(B), self.negatives.sample(B)], 0).to(self.device)
        labels = torch.cat([torch.ones(B), torch.zeros(B)]).to(self.device)
        with self._autocast():
            loss, stats = _bce_step_stats(self.reward.classifier(self.reward.features(data)), labels)
        self._train_step(loss, (self.optim,))
        self.reward.classifier.trained.fill_(True)
        return stats

    def log_row(self):
        return {"classifier_positives": float(len(self.positives)), "classifier_negatives": float(len(self.negatives))}

    def summary(self):
        return self.log_row()

    def optimizers(self):
        return {"classifier": self.optim}

    def dump_buffers(self, directory: Path) -> None:
        for name in ("positives", "negatives"):
            if len(getattr(self, name)):
                dump_buffer(getattr(self, name), Path(directory) / f"classifier_{name}")

    def load_buffers(self, directory: Path) -> None:
        for name in ("positives", "negatives"):
            if (Path(directory) / f"classifier_{name}").exists():
                getattr(
                    self, name
                ).empty()  # e.g. ORIL's demonstrations, added again by the constructor, are in the snapshot
                load_buffer(getattr(self, name), Path(directory) / f"classifier_{name}")


class SuccessClassifierLearner(_TwoSetClassifier):
    """VICE-RAQ with an oracle (Sec. 5.2): every visited state is labelled by the success indicator."""

    name = "vice_raq"

    def __init__(
        self,
        reward: ClassifierReward,
        *,
        success_key: str = "success",
        success_states: TensorDictBase | None = None,
        demos: list[TensorDictBase] | None = None,
        **kw,
    ):
        """``success_states``: optional success states to start the positives with (the maze gives its
        demonstrations' goals). ``demos`` is not read: the run gives every learned reward its demonstrations, and
        VICE-RAQ's positives are the success states the agent visits (Sec. 5.2); a run's demonstrations still feed
        SAC's batch (``demos.sac_share``)."""
        super().__init__(reward, **kw)
        self.success_key = success_key
        if success_states is not None and success_states.numel():
            self.positives.extend(self._states(success_states))

    def observe(self, batch, episodes):
        nxt = batch.get("next").reshape(-1)
        success = nxt.get(self.success_key).reshape(-1).to(torch.bool)
        states = self._states(nxt)
        if bool(success.any()):
            self.positives.extend(states[success])
        if not bool(success.all()):
            self.negatives.extend(states[~success])

    def update(self):
        out = None
        for _ in range(self._steps_due()):
            step = self._step()
            out = step if step is not None else out
        return out


class OfflineClassifierLearner(_TwoSetClassifier):
    """ORIL's reward (Sec. 5.2): demonstration states vs random-trajectory states, learned offline.

    :meth:`prepare` rolls out ``random_episodes`` episodes of uniformly random actions in the training
    env, then takes ``offline_updates`` classifier steps; the reward stays frozen afterwards.
    """

    name = "oril"

    def __init__(
        self,
        reward: ClassifierReward,
        *,
        demos: list[TensorDictBase],
        random_episodes: int = 100,
        offline_updates: int = 2000,
        **kw,
    ):
        super().__init__(reward, **kw)
        if not demos:
            raise ValueError("reward=oril learns from demonstrations: give demos.path=DIR (drs-demos writes them)")
        self.positives.extend(torch.cat([self._states(ep) for ep in demos], 0))
        self.random_episodes, self.offline_updates = int(random_episodes), int(offline_updates)
        self.random_states = 0

    def prepare(self, env) -> None:
        states = []
        with torch.no_grad():
            for _ in range(self.random_episodes):
                ep = env.rollout(100_000, break_when_any_done=True)  # no policy: uniformly random actions
                while ep.batch_dims > 1:
                    ep = ep[0]
                states.append(self._states(ep.get("next")))
        self.fit_offline(torch.cat(states, 0))

    def fit_offline(self, random_states: TensorDictBase) -> TensorDict | None:
        """Train on the demonstrations vs ``random_states`` for ``offline_updates`` steps."""
        self.negatives.extend(self._states(random_states))
        self.random_states = len(self.negatives)
        stats = None
        for _ in range(self.offline_updates):
            stats = self._step()
        return stats

    def summary(self):
        return {**super().summary(), "offline_updates": self.updates, "random_episodes": self.random_episodes}


class _ProbabilityOf(nn.Module):
    """``D(x, a)`` as a probability, the output :class:`~torchrl.objectives.GAILLoss` expects. Not clipped
    (the reward clips its logits, not the loss): a clip here would leave a confidently wrong sample without
    a gradient."""

    def __init__(self, reward: ClassifierReward):
        super().__init__()
        self.classifier = reward.classifier

    def forward(self, state_features: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.classifier(torch.cat([state_features, action], -1)).float())


class DemoDiscriminatorLearner(RewardLearner):
    """GAIL's discriminator (Appendix F.2): demonstrations (label 1) vs the agent's transitions (0).

    Reads ``(s, a)`` when the reward does (demonstrations then need their actions and the states
    they were taken in: ``drs-demos --from-policy`` records both), else the next states ``s'``.
    Agent samples come from the RL replay buffer (:meth:`attach`), off-policy as in DAC.
    """

    name = "gail"

    def __init__(
        self,
        reward: ClassifierReward,
        *,
        demos: list[TensorDictBase],
        batch_size: int = 256,
        lr: float = 3e-4,
        fused: bool = False,
        reward_updates_per_update: float = 1,
        grad_penalty: bool = False,
        **kw,
    ):
        super().__init__(**kw)
        if not demos:
            raise ValueError("reward=gail imitates demonstrations: give demos.path=DIR (drs-demos writes them)")
        self.reward = reward
        if reward.use_action:
            lacking = [k for k in ("action", "state") if k not in demos[0].keys()]
            if lacking:
                raise ValueError(
                    f"reward=gail reads (s, a), but the demonstrations lack {lacking} (recorded before actions were "
                    "kept, or by a motion planner in another controller); record them with drs-demos --from-policy, "
                    "or learn on states only with reward.use_action=false"
                )
            self.demo_x = torch.cat([reward.state_features(ep.get("state")) for ep in demos], 0)
            self.demo_a = torch.cat([ep.get("action").to(torch.float32) for ep in demos], 0)
        else:
            self.demo_x = torch.cat([reward.state_features(ep) for ep in demos], 0)
            self.demo_a = self.demo_x.new_zeros(self.demo_x.shape[0], 0)
        self.batch_size = int(batch_size)
        self._set_reward_updates_per_update(reward_updates_per_update)
        disc = TensorDictModule(_ProbabilityOf(reward), in_keys=["observation", "action"], out_keys=["d_logits"])
        self.loss = GAILLoss(disc, use_grad_penalty=bool(grad_penalty))
        self.optim = torch.optim.Adam(reward.classifier.parameters(), lr=float(lr), fused=bool(fused))
        self.replay = None

    def attach(self, replay) -> None:
        self.replay = replay

    def _agent(self, B: int) -> tuple[torch.Tensor, torch.Tensor]:
        idx = torch.randint(len(self.replay), (B,))
        td = self.replay.storage[idx]
        if self.reward.use_action:
            return self.reward.state_features(td), td.get("action").to(torch.float32)
        x = self.reward.state_features(td.get("next"))
        return x, x.new_zeros(B, 0)

    def update(self):
        if self.replay is None or len(self.replay) == 0:
            return None
        out = None
        for _ in range(self._steps_due()):
            B = self.batch_size
            i = torch.randint(self.demo_x.shape[0], (B,))
            agent_x, agent_a = self._agent(B)
            batch = TensorDict(
                {
                    "observation": self.demo_x[i],
                    "action": self.demo_a[i],
                    "collector_observation": agent_x,
                    "collector_action": agent_a,
                },
                batch_size=[B],
            ).to(self.device)
            with self._autocast():
                out = self.loss(batch)
            loss = out["loss"]  # GAILLoss adds the gradient penalty into it (its "gp_loss" is a detached copy)
            self._train_step(loss, (self.optim,))
            self.reward.classifier.trained.fill_(True)
            with torch.no_grad():  # one pass over both sides, for the logged accuracy
                z = self.reward.classifier(
                    torch.cat(
                        [
                            torch.cat([batch["observation"], batch["action"]], -1),
                            torch.cat([batch["collector_observation"], batch["collector_action"]], -1),
                        ]
                    )
                )
            acc = 0.5 * ((z[:B] > 0).float().mean() + (z[B:] <= 0).float().mean())
            out = TensorDict({"loss": loss.detach(), "accuracy": acc}, batch_size=[])
        return out

    def optimizers(self):
        return {"discriminator": self.optim}

    def log_row(self):
        return {"demo_transitions": float(self.demo_x.shape[0])}
