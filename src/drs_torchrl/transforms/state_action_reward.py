"""A learned reward on transitions ``R(s, a)`` (the appendix's tabular analysis, the maze) or ``R(s')`` (Sec. 4.3)
written into ``("next", "reward")``, as an env transform or a replay-buffer transform."""

from __future__ import annotations

from collections.abc import Callable

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.envs.transforms import Transform

from drs_torchrl.transforms.classifier_reward import ClassifierReward
from drs_torchrl.transforms.reward import DrSReward


class StateActionReward(Transform):
    """Write the learned reward of transitions into ``("next", "reward")``.

    ``reward`` is a :class:`DrSReward` whose ``reward_in_keys`` (e.g. ``observation`` and ``action``) are read at the
    root of a transition, so they describe ``(s, a)``; the stage index is read from ``("next", stage)``, the stage of
    ``s'``. A reward learned on next states (metadata ``reward_on: next_state``) reads its inputs from ``"next"``:
    ``R(s')`` as in Sec. 4.3. A :class:`ClassifierReward` (the learned baselines) reads (s, a) or s' itself.
    As a replay-buffer transform (``forward``) it recomputes rewards from the current discriminator each time the
    agent samples (Algorithm 1, line 18); inside a :class:`~torchrl.envs.TransformedEnv` (``_step``, after the
    :class:`~drs_torchrl.transforms.StageIndicator`) it writes the reward of each step as it is taken.
    ``observation_map``: re-encodes the env's observations into what the reward was learned on (None: as they are);
    ``scale`` multiplies the reward the agent sees (the discriminator is untouched). The env's reward spec already
    describes the entry it rewrites, so it declares no new key.
    """

    def __init__(
        self,
        reward: DrSReward | ClassifierReward,
        *,
        scale: float = 1.0,
        observation_map: Callable[[torch.Tensor], torch.Tensor] | None = None,
    ):
        super().__init__()
        self.drs = reward
        self.scale = float(scale)
        self.observation_map = observation_map
        self.on_next_state = reward.metadata.get("reward_on") == "next_state"

    def _reward(self, root: TensorDictBase, nxt: TensorDictBase) -> torch.Tensor:
        if isinstance(self.drs, ClassifierReward):
            r = self.drs.reward_of(root, nxt, root.get(self.drs.action_key, None))
            return r * self.scale if self.scale != 1.0 else r
        src = nxt if self.on_next_state else root
        sa = TensorDict({k: src.get(k) for k in self.drs.reward_in_keys}, batch_size=root.batch_size)
        if self.observation_map is not None:
            sa.set("observation", self.observation_map(sa.get("observation")))
        sa.set(self.drs.stage_key, nxt.get(self.drs.stage_key))
        r = self.drs.reward(sa)
        return r * self.scale if self.scale != 1.0 else r

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        tensordict.set(("next", self.drs.reward_key), self._reward(tensordict, tensordict.get("next")))
        return tensordict

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        next_tensordict.set(self.drs.reward_key, self._reward(tensordict, next_tensordict))
        return next_tensordict
