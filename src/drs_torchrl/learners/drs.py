"""DrS's reward learning (Sec. 4, Algorithm 1): stage buffers, one discriminator per stage, demos."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase

from drs_torchrl.data import StageBuffers
from drs_torchrl.data.stage_buffers import trajectory_stage
from drs_torchrl.data.persistence import dump_buffer, load_buffer
from drs_torchrl.learners.base import RewardLearner
from drs_torchrl.objectives import DiscriminatorLoss
from drs_torchrl.transforms.reward import DrSReward


class DrSLearner(RewardLearner):
    """Files every finished episode into the stage buffer of the highest stage it reached
    (:class:`~drs_torchrl.data.StageBuffers`) and trains discriminator ``k`` on "got beyond stage k"
    vs "stopped at k or before" (:class:`~drs_torchrl.objectives.DiscriminatorLoss`, early stop of Sec. 4.3).

    Args:
        reward: the :class:`~drs_torchrl.transforms.DrSReward` it trains (in place).
        capacity, batch_size, scratch_dir: stage-buffer size per stage, discriminator batch per side,
            optional on-disk storage.
        lr, fused: Adam of the discriminators.
        reward_updates_per_update: discriminator steps per RL update (the authors': 1; may be fractional, e.g. 0.5).
        early_stop_threshold, window, latch: see :class:`~drs_torchrl.objectives.DiscriminatorLoss`.
        demos: successful trajectories (``(T,)`` TensorDicts of states) for the top buffer (line 3).
        file_successes: False keeps the agent's successful episodes out of the top buffer (they still
            count towards the early stop), so its positives are the demonstrations alone: the
            near-optimal success buffer the appendix's tabular argument assumes.
    """

    name = "drs"
    stage_buffers_hold_demos = True

    def __init__(
        self,
        reward: DrSReward,
        *,
        capacity: int = 1_000_000,
        batch_size: int = 256,
        scratch_dir=None,
        lr: float = 3e-4,
        fused: bool = False,
        reward_updates_per_update: float = 1,
        early_stop_threshold: float | None = 0.95,
        window: int = 100,
        latch: bool = True,
        demos: list[TensorDictBase] | None = None,
        file_successes: bool = True,
        **kw,
    ):
        super().__init__(**kw)
        self.reward = reward
        self.stage_buffers = StageBuffers(
            reward.num_stages,
            reward.reward_in_keys,
            capacity=int(capacity),
            batch_size=int(batch_size),
            scratch_dir=scratch_dir,
        )
        self.loss = DiscriminatorLoss(
            reward.discriminators,
            reward.reward_in_keys,
            early_stop_threshold=early_stop_threshold,
            window=int(window),
            latch=bool(latch),
        )
        self.optim = torch.optim.Adam(reward.discriminators.parameters(), lr=float(lr), fused=bool(fused))
        self._set_reward_updates_per_update(reward_updates_per_update)
        self.num_demos = 0
        self.file_successes = bool(file_successes)
        for ep in demos or ():
            self.stage_buffers.add_trajectory(TensorDict({"next": ep}, batch_size=ep.shape), demo=True)
            self.num_demos += 1

    def observe(self, batch, episodes):
        if episodes:
            self.loss.record_episodes([self._file(ep) for ep in episodes])

    def _file(self, episode: TensorDictBase) -> int:
        top = self.reward.num_stages
        if not self.file_successes and trajectory_stage(episode.get(("next", self.stage_buffers.stage_key))) == top:
            return top
        return self.stage_buffers.add_trajectory(episode)

    def update(self) -> TensorDict | None:
        if len(self.stage_buffers) == 0:
            return None
        out = None
        for _ in range(self._steps_due()):
            batch = self.stage_buffers.sample_discriminator_batch().to(self.device)
            with self._autocast():
                out = self.loss(batch)
            loss = out["loss_discriminator"]
            if loss.requires_grad:
                self._train_step(loss, (self.optim,))
        return None if out is None else out.detach()

    def log_row(self) -> dict[str, float]:
        row = {f"stage_buffer_{s}": float(c) for s, c in enumerate(self.stage_buffers.stage_counts())}
        row.update({f"beyond_rate_{k}": v for k, v in enumerate(self.loss.beyond_rates().tolist())})
        return row

    def summary(self) -> dict[str, Any]:
        return {
            "stage_buffer_transitions": self.stage_buffers.stage_counts().tolist(),
            "stage_buffer_episodes": self.stage_buffers.episodes_per_stage.tolist(),
        }

    def optimizers(self):
        return {"discriminator": self.optim}

    def state_dict(self) -> dict[str, Any]:
        return {
            **super().state_dict(),
            "disc_loss": self.loss.state_dict(),
            "stage_buffer_episodes": self.stage_buffers.episodes_per_stage.tolist(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        self.loss.load_state_dict(state["disc_loss"])
        self.stage_buffers.episodes_per_stage = np.asarray(state["stage_buffer_episodes"], dtype=np.int64)

    def dump_buffers(self, directory: Path) -> None:
        dump_buffer(self.stage_buffers, Path(directory) / "stage_buffers")

    def load_buffers(self, directory: Path) -> None:
        load_buffer(self.stage_buffers, Path(directory) / "stage_buffers")
