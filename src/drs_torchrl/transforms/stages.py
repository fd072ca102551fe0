"""Stage labelling (Sec. 3, Eq. 2 and Eq. 3 of the DrS paper).

:class:`StageIndicator` reads a task's ordered boolean stage indicators (the last one is success),
makes them monotone (reaching a later stage implies the earlier ones: the authors' TurnFaucet and
OpenCabinetDoor indicators are built so; their PickAndPlace sums the raw ones, so a cube released at
the goal counts as placed but not grasped there, and as past both here), and writes the integer stage
index ``k`` of the state, ``0 <= k <= N``.
:class:`SemiSparseReward` turns that index into the semi-sparse reward ``R(s') = k`` (Eq. 2).
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
    """Write the stage index of each next state (Eq. 3) and its monotone indicators.

    Args:
        stage_keys: ordered indicator keys, success last (e.g.
            ``["is_grasped", "is_obj_placed", "success"]``); each entry is boolean ``(*batch, 1)``.
        stage_key: where the integer stage index goes (``int64``, ``(*batch, 1)``).
        indicators_key: where the monotone indicators go as a float vector ``(*batch, N)`` (a
            reward input, as the public implementation appends them to the observation);
            ``None`` to skip.

    Works in a :class:`~torchrl.envs.TransformedEnv`, on replay-buffer samples (``forward`` labels
    the ``"next"`` entries) and on bare TensorDicts. A missing indicator raises a ``KeyError`` naming it.
    """

    def __init__(
        self, stage_keys: Sequence[str], stage_key: str = "stage", indicators_key: str | None = "stage_indicators"
    ):
        stage_keys = list(stage_keys)
        if not stage_keys:
            raise ValueError("StageIndicator needs at least one indicator key (success)")
        out_keys = [stage_key] + ([indicators_key] if indicators_key else [])
        super().__init__(in_keys=stage_keys, out_keys=out_keys)
        self.stage_keys = stage_keys
        self.stage_key = stage_key
        self.indicators_key = indicators_key

    @property
    def num_stages(self) -> int:
        return len(self.stage_keys)

    def label(self, td: TensorDictBase) -> TensorDictBase:
        """Label a TensorDict whose indicator entries are at its root."""
        ind = torch.cat([_require(td, k, "stage indicator").to(torch.bool) for k in self.stage_keys], dim=-1)
        mono = monotone_indicators(ind)
        td.set(self.stage_key, mono.sum(-1, keepdim=True))
        if self.indicators_key:
            td.set(self.indicators_key, mono.to(torch.float32))
        return td

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        return self.label(next_tensordict)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return self.label(tensordict_reset)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if "next" in tensordict.keys():
            self.label(tensordict.get("next"))
            return tensordict
        return self.label(tensordict)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        if self.stage_keys[0] not in observation_spec.keys(True, True):
            raise KeyError(
                f"stage indicator {self.stage_keys[0]!r} is not in the observation spec "
                f"(it has {sorted(map(str, observation_spec.keys(True, True)))})"
            )
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
        return f"{type(self).__name__}(stage_keys={self.stage_keys})"


class SemiSparseReward(Transform):
    """The semi-sparse reward of Eq. 2, ``R(s') = scale * (k + offset)``, from the stage index a
    :class:`StageIndicator` wrote (``offset=-N`` keeps every reward <= 0, for tasks that end on success).

    Declares ``reward_key`` as float32 within its bounds; nothing is written on reset. ``scale`` is here
    because TorchRL's ``RewardScaling`` refuses a bounded reward spec.
    """

    def __init__(
        self,
        num_stages: int,
        offset: float = 0.0,
        stage_key: str = "stage",
        reward_key: str = "reward",
        scale: float = 1.0,
    ):
        if num_stages < 1:
            raise ValueError(f"num_stages must be >= 1, got {num_stages}")
        if not scale > 0:
            raise ValueError(f"scale must be > 0, got {scale}")
        super().__init__(in_keys=[stage_key], out_keys=[reward_key])
        self.num_stages, self.offset, self.scale = int(num_stages), float(offset), float(scale)
        self.stage_key, self.reward_key = stage_key, reward_key

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        stage = _require(next_tensordict, self.stage_key, "stage index (add a StageIndicator before it)")
        next_tensordict.set(self.reward_key, self.scale * (stage.to(torch.float32) + self.offset))
        return next_tensordict

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if "next" in tensordict.keys():
            self._call(tensordict.get("next"))
            return tensordict
        return self._call(tensordict)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return tensordict_reset

    def transform_reward_spec(self, reward_spec: Composite) -> Composite:
        shape = reward_spec[self.reward_key].shape if self.reward_key in reward_spec.keys() else (*reward_spec.shape, 1)
        reward_spec[self.reward_key] = Bounded(
            self.scale * self.offset,
            self.scale * (self.num_stages + self.offset),
            shape=shape,
            dtype=torch.float32,
            device=reward_spec.device,
        )
        return reward_spec

    def __repr__(self) -> str:
        return f"{type(self).__name__}(num_stages={self.num_stages}, offset={self.offset:g}, scale={self.scale:g})"


def _require(td: TensorDictBase, key, what: str) -> torch.Tensor:
    value = td.get(key, None)
    if value is None:
        raise KeyError(f"{what} {key!r} is missing from the TensorDict (it holds {sorted(map(str, td.keys()))})")
    return value
