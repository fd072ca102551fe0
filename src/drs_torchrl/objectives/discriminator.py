"""Per-stage discriminator loss of DrS (Sec. 4.2-4.3, Algorithm 1 lines 11-15).

Discriminator ``k`` learns, with binary cross-entropy, "this state comes from a trajectory that got
beyond stage k" (positives, stage buffers ``k+1..N``) vs "from one that stopped at stage <= k"
(negatives, buffers ``0..k``). Training of discriminator ``k`` pauses while the rolling rate of
training episodes that get beyond stage ``k`` is above a threshold (0.95), as in Sec. 4.3.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from tensordict import TensorDict, TensorDictBase
from torchrl.objectives import LossModule

from drs_torchrl.transforms.reward import StageDiscriminators


class DiscriminatorLoss(LossModule):
    """BCE loss of every stage discriminator on a ``(N, 2, B)`` batch from :class:`StageBuffers`.

    Args:
        discriminators: the modules held by :class:`~drs_torchrl.transforms.DrSReward`
            (``reward.discriminators``): training them changes the reward in place.
        in_keys: reward input entries of the batch (concatenated as in the reward).
        early_stop_threshold: a discriminator trains only while the rolling rate of training
            episodes that get beyond its stage is ``<=`` this value (``None`` or ``>= 1``: always).
        window: number of recent training episodes in that rolling rate; nothing stops before
            that many episodes have been recorded.
        latch: once a stage passes the threshold its discriminator stops for good (the authors'
            code); ``False`` resumes training whenever the rate falls back.

    Returns (``forward``) a TensorDict with ``loss_discriminator`` (sum over the stages that train)
    and, per stage ``k``, ``loss_k``, ``accuracy_k`` (on that batch) and ``active_k``.
    """

    def __init__(
        self,
        discriminators: StageDiscriminators,
        in_keys: Sequence[str],
        *,
        label_key: str = "label",
        valid_key: str = "valid",
        early_stop_threshold: float | None = 0.95,
        window: int = 100,
        latch: bool = True,
    ):
        super().__init__()
        if window < 1:
            raise ValueError("window must be >= 1")
        self.discriminators = discriminators
        self.in_keys = list(in_keys)
        self.label_key = label_key
        self.valid_key = valid_key
        self.early_stop_threshold = early_stop_threshold
        self.num_stages = discriminators.num_stages
        self.register_buffer("recent_stages", torch.full((window,), -1, dtype=torch.long))
        self.register_buffer("recent_pos", torch.zeros((), dtype=torch.long))
        self.register_buffer("stopped", torch.zeros(self.num_stages, dtype=torch.bool))
        self.latch = latch

    # ----------------------------------------------------------- early stopping
    def record_episodes(self, stages: torch.Tensor | Sequence[int]) -> None:
        """Record the trajectory stage index of finished training episodes."""
        for s in torch.as_tensor(stages, dtype=torch.long).reshape(-1).tolist():
            w = self.recent_stages.numel()
            self.recent_stages[int(self.recent_pos) % w] = s
            self.recent_pos += 1

    def beyond_rates(self) -> torch.Tensor:
        """Rolling rate, over recent training episodes, of getting beyond each stage ``k < N``."""
        seen = self.recent_stages[self.recent_stages >= 0]
        if seen.numel() == 0:
            return torch.zeros(self.num_stages)
        ks = torch.arange(self.num_stages)
        return (seen[:, None] > ks[None, :]).float().mean(0)

    def training_mask(self) -> torch.Tensor:
        """Which discriminators still train (early stop of Sec. 4.3)."""
        if self.early_stop_threshold is None or self.early_stop_threshold >= 1:
            return torch.ones(self.num_stages, dtype=torch.bool)
        if int(self.recent_pos) < self.recent_stages.numel():  # judge only a full window of episodes
            return ~self.stopped
        passed = self.beyond_rates() > self.early_stop_threshold
        if self.latch:
            self.stopped |= passed
            return ~self.stopped
        return ~passed

    # --------------------------------------------------------------------- loss
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        N = self.num_stages
        if tensordict.shape[:2] != torch.Size([N, 2]):
            raise ValueError(
                f"expected a (N={N}, 2, B) batch from StageBuffers.sample_discriminator_batch, got {tuple(tensordict.shape)}"
            )
        x = torch.cat([tensordict.get(k).to(torch.float32) for k in self.in_keys], dim=-1)
        y = tensordict.get(self.label_key).squeeze(-1).to(torch.float32)
        valid = (
            tensordict.get(self.valid_key).reshape(N, -1)[:, 0].to(torch.bool)
            if self.valid_key in tensordict.keys()
            else torch.ones(N, dtype=torch.bool)
        )
        active = valid & self.training_mask().to(valid.device)
        out = {}
        total = x.new_zeros(())
        for k in range(N):
            logits = self.discriminators.stage_logits(x[k], k).float()  # fp32 loss under autocast
            loss_k = F.binary_cross_entropy_with_logits(logits, y[k])
            with torch.no_grad():
                acc_k = ((logits > 0).float() == y[k]).float().mean()
            if active[k]:
                total = total + loss_k
                self.discriminators.trained[k] = True  # this loss is about to train it
            out[f"loss_{k}"] = loss_k.detach()
            out[f"accuracy_{k}"] = acc_k
            out[f"active_{k}"] = active[k].float()
        out["loss_discriminator"] = total
        return TensorDict(out, batch_size=[])
