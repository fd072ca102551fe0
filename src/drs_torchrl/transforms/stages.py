"""Stage labelling (Sec. 3, Eq. 2 and Eq. 3 of the DrS paper).

:class:`StageIndicator` reads a task's ordered boolean stage indicators (the last one is success),
makes them monotone (reaching a later stage implies the earlier ones, as the authors' code does),
and writes the integer stage index ``k`` of the state, ``0 <= k <= N``. It can also emit the
semi-sparse reward ``R(s') = k`` (Eq. 2).
"""
from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from torchrl.data import Bounded, Composite
from torchrl.envs.transforms import Transform


def monotone_indicators(indicators: torch.Tensor) -> torch.Tensor:
    """Make stage indicators monotone along the last dim: ``m_i = any(ind_j for j >= i)``."""
    ind = indicators.to(torch.bool)
    # reversed cumulative OR
    return ind.flip(-1).cummax(-1).values.flip(-1)


def stage_index(indicators: torch.Tensor) -> torch.Tensor:
    """Stage index of a state: the number of monotone indicators that hold (``k`` in Eq. 2/4)."""
    return monotone_indicators(indicators).sum(-1)


class StageIndicator(Transform):
    """Write the stage index (and, optionally, the semi-sparse reward) of each next state.

    Args:
        stage_keys: ordered indicator keys, success last (e.g.
            ``["is_grasped", "is_obj_placed", "success"]``); each entry is boolean ``(*batch, 1)``.
        stage_key: where the integer stage index goes (``int64``, ``(*batch, 1)``).
        indicators_key: where the monotone indicators go as a float vector ``(*batch, N)`` (a
            reward input, as the public implementation appends them to the observation);
            ``None`` to skip.
        semi_sparse_reward: if ``True``, overwrite ``"reward"`` with ``k + semi_sparse_offset`` (Eq. 2;
            an offset of ``-N`` makes every reward <= 0, for tasks that terminate on success).

    Works in a :class:`~torchrl.envs.TransformedEnv`, on replay-buffer samples (``forward`` labels
    the ``"next"`` entries) and on bare TensorDicts.
    """

    def __init__(
        self,
        stage_keys: Sequence[str],
        stage_key: str = "stage",
        indicators_key: str | None = "stage_indicators",
        semi_sparse_reward: bool = False,
        reward_key: str = "reward",
        semi_sparse_offset: float = 0.0,
    ):
        stage_keys = list(stage_keys)
        if not stage_keys:
            raise ValueError("StageIndicator needs at least one indicator key (success)")
        out_keys = [stage_key] + ([indicators_key] if indicators_key else [])
        super().__init__(in_keys=stage_keys, out_keys=out_keys)
        self.stage_keys = stage_keys
        self.stage_key = stage_key
        self.indicators_key = indicators_key
        self.semi_sparse_reward = semi_sparse_reward
        self.reward_key = reward_key
        self.semi_sparse_offset = float(semi_sparse_offset)

    @property
    def num_stages(self) -> int:
        return len(self.stage_keys)

    def label(self, td: TensorDictBase, write_reward: bool = True) -> TensorDictBase:
        """Label a TensorDict whose indicator entries are at its root."""
        ind = torch.cat([td.get(k).to(torch.bool) for k in self.stage_keys], dim=-1)
        mono = monotone_indicators(ind)
        stage = mono.sum(-1, keepdim=True)
        td.set(self.stage_key, stage)
        if self.indicators_key:
            td.set(self.indicators_key, mono.to(torch.float32))
        if self.semi_sparse_reward and write_reward:
            td.set(self.reward_key, stage.to(torch.float32) + self.semi_sparse_offset)
        return td

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        return self.label(next_tensordict)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return self.label(tensordict_reset, write_reward=False)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if "next" in tensordict.keys():
            self.label(tensordict.get("next"))
            return tensordict
        return self.label(tensordict)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        ref = observation_spec[self.stage_keys[0]]
        shape = ref.shape[:-1]
        observation_spec[self.stage_key] = Bounded(
            low=0, high=self.num_stages, shape=(*shape, 1), dtype=torch.int64, device=ref.device
        )
        if self.indicators_key:
            observation_spec[self.indicators_key] = Bounded(
                low=0.0, high=1.0, shape=(*shape, self.num_stages), dtype=torch.float32, device=ref.device
            )
        return observation_spec

    def __repr__(self) -> str:
        return f"{type(self).__name__}(stage_keys={self.stage_keys}, semi_sparse_reward={self.semi_sparse_reward})"
