"""The reward of the paper's classifier baselines (Sec. 5.2, Appendix F.2) as a TorchRL transform.

One binary classifier ``D`` scores a state (``s'``) or a state-action pair (``(s, a)``); the reward
is a function of its logit. What the classifier separates is the learner's business
(:mod:`drs_torchrl.learners`):

* VICE-RAQ: success states (the oracle's success indicator, queried for every state) vs every other
  state the agent visits;
* ORIL: states of demonstrations vs states of random-policy trajectories, learned offline;
* GAIL: demonstrations vs the agent's own transitions; ``gail_stages`` adds the semi-sparse stage
  reward in reuse, ``r = w_c * r_D + w_s * (k - N)`` (Appendix F.2, "GAIL w/ Stage Indicators").

Output (``output=``), chosen so that every step costs, as for every reward of this project (episodes
end on success, so a reward of at most 0 makes reaching success sooner worth more, never hovering):
``"log_sigmoid"``, ``log D`` (VICE's ``log p(success | s)``; GAIL's minimax reward), logits clipped to
``[-10, 10]``; ``"sigmoid"``, ``D`` (ORIL's reward), plus ``offset`` (-1: in ``[-1, 0]``).
An untrained classifier contributes its value at logit 0.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from tensordict import TensorDictBase
from torch import nn
from torchrl.envs.transforms import Transform

from drs_torchrl.transforms.reward import (
    _ACTIVATIONS,
    LearnedRewardChecks,
    input_sizes,
    RewardCheckpointError,
    bounded_reward_spec,
    check_stages,
    checkpoint_config,
    load_checked,
    read_reward_checkpoint,
    require,
    write_reward_checkpoint,
)

OUTPUTS = ("log_sigmoid", "sigmoid")
CLASSIFIER_SETTINGS = (  # what a checkpoint's settings must name
    "in_keys",
    "in_shapes",
    "num_stages",
    "use_action",
    "action_dim",
    "action_key",
    "stage_key",
    "output",
    "offset",
    "classifier_weight",
    "stage_weight",
    "hidden",
    "activation",
    "reward_key",
    "method",
)
LOGIT_CLIP = 10.0


class Classifier(nn.Module):
    """An MLP with one logit, and a ``trained`` flag (an untrained one scores logit 0)."""

    def __init__(self, in_features: int, hidden: Sequence[int] | int = (32,), activation: str = "sigmoid"):
        super().__init__()
        if activation not in _ACTIVATIONS:
            raise ValueError(f"activation must be one of {sorted(_ACTIVATIONS)}, got {activation!r}")
        hidden = [hidden] if isinstance(hidden, int) else list(hidden)
        self.in_features, self.hidden, self.activation = in_features, hidden, activation
        layers, d = [], in_features
        for h in hidden:
            layers += [nn.Linear(d, h), _ACTIVATIONS[activation]()]
            d = h
        layers.append(nn.Linear(d, 1))
        self.net = nn.Sequential(*layers)
        self.register_buffer("trained", torch.zeros((), dtype=torch.bool))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Logits, shape ``(*batch, 1)``."""
        return self.net(x)


class ClassifierReward(LearnedRewardChecks, Transform):
    """Reward ``w_c * f(D(x)) + w_s * (k - N)`` of one classifier ``D`` (module docstring).

    Args:
        in_keys: state entries ``D`` reads (concatenated), e.g. ``["observation", "stage_indicators"]``.
        in_shapes: trailing size of each of them.
        num_stages: ``N`` (for the stage term and the compatibility check).
        use_action: ``D`` reads ``(s, a)`` (root state and ``action``) instead of ``s'``.
        action_dim: size of the action (with ``use_action``).
        output: ``"log_sigmoid"`` or ``"sigmoid"``; ``offset`` is added to it.
        classifier_weight, stage_weight: ``w_c`` and ``w_s`` (``w_s = 0``: no stage term).
        method: the baseline that learned it (``vice_raq``, ``oril``, ``gail``), for the record.

    Works in a :class:`~torchrl.envs.TransformedEnv`, as a replay-buffer transform (``forward`` reads
    the root and ``"next"`` of transitions and writes ``("next", reward_key)``), and on bare states.
    """

    def __init__(
        self,
        in_keys: Sequence[str],
        in_shapes: Mapping[str, int],
        num_stages: int,
        *,
        use_action: bool = False,
        action_dim: int | None = None,
        action_key: str = "action",
        stage_key: str = "stage",
        output: str = "log_sigmoid",
        offset: float = 0.0,
        classifier_weight: float = 1.0,
        stage_weight: float = 0.0,
        hidden: Sequence[int] | int = (32,),
        activation: str = "sigmoid",
        reward_key: str = "reward",
        method: str = "classifier",
        metadata: Mapping[str, Any] | None = None,
    ):
        if output not in OUTPUTS:
            raise ValueError(f"output must be one of {OUTPUTS}, got {output!r}")
        in_keys = list(in_keys)
        missing = [k for k in in_keys if k not in in_shapes]
        if missing:
            raise ValueError(f"in_shapes lacks the sizes of {missing}")
        if use_action and not action_dim:
            raise ValueError("use_action=True needs action_dim")
        reads = [*in_keys, stage_key] + ([action_key] if use_action else [])
        super().__init__(in_keys=reads, out_keys=[reward_key])
        self.reward_in_keys = in_keys
        self.in_shapes = {k: int(in_shapes[k]) for k in in_keys}
        self.num_stages, self.stage_key, self.reward_key = int(num_stages), stage_key, reward_key
        self.use_action, self.action_dim, self.action_key = (
            bool(use_action),
            (int(action_dim) if use_action else None),
            action_key,
        )
        self.output, self.offset = output, float(offset)
        self.classifier_weight, self.stage_weight = float(classifier_weight), float(stage_weight)
        self.method = method
        self.metadata = dict(metadata or {})
        self.classifier = Classifier(sum(self.in_shapes.values()) + (self.action_dim or 0), hidden, activation)

    @classmethod
    def from_env(
        cls, env, num_stages: int, in_keys: Sequence[str], *, use_action: bool = False, offset=0.0, **kwargs
    ) -> "ClassifierReward":
        """A fresh classifier for a baseline's phase 1, sized from ``env``'s specs (the action's with
        ``use_action``): the ``model`` builder of ``conf/reward/{vice_raq,oril,gail}.yaml``; ``offset`` null is 0."""
        in_keys = list(in_keys)
        kwargs["offset"] = float(offset or 0.0)
        action_dim = int(env.action_spec.shape[-1]) if use_action else None
        return cls(
            in_keys,
            input_sizes(env.observation_spec, in_keys),
            num_stages,
            use_action=use_action,
            action_dim=action_dim,
            **kwargs,
        )

    # ------------------------------------------------------------ reward math
    def state_features(self, state: TensorDictBase) -> torch.Tensor:
        """The state entries ``D`` reads, concatenated."""
        return torch.cat([require(state, k).to(self._dtype) for k in self.reward_in_keys], dim=-1)

    def features(self, state: TensorDictBase, action: torch.Tensor | None = None) -> torch.Tensor:
        """``D``'s input: the state features, and the action when it reads ``(s, a)``."""
        x = self.state_features(state)
        if not self.use_action:
            return x
        if action is None:
            raise KeyError(f"this reward reads (s, a): the transition lacks {self.action_key!r}")
        return torch.cat([x, action.to(self._dtype)], dim=-1)

    @property
    def _dtype(self) -> torch.dtype:
        """The classifier's parameter dtype: inputs follow ``.double()`` / ``.to(dtype)`` of the transform."""
        return next(self.classifier.parameters()).dtype

    def logits(self, state: TensorDictBase, action: torch.Tensor | None = None) -> torch.Tensor:
        return self.classifier(self.features(state, action))

    def combine(self, logits: torch.Tensor, stage: torch.Tensor) -> torch.Tensor:
        """The reward from logits ``(*b, 1)`` and stage indices ``(*b, 1)``."""
        z = logits.clamp(-LOGIT_CLIP, LOGIT_CLIP)
        if not bool(self.classifier.trained):
            z = torch.zeros_like(z)
        r = F.logsigmoid(z) if self.output == "log_sigmoid" else torch.sigmoid(z)
        r = self.classifier_weight * (r + self.offset)
        if self.stage_weight:  # GAIL with stages (Appendix F.2): a stage outside [0, N] is refused, as by DrSReward
            r = r + self.stage_weight * (
                check_stages(stage, self.num_stages, self.stage_key).to(r.dtype) - self.num_stages
            )
        return r

    def reward_of(
        self, state: TensorDictBase, next_state: TensorDictBase, action: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Reward of transitions ``(s, a, s')`` (``(*batch, 1)``), without gradients: ``D`` reads
        ``s'`` or ``(s, a)``; the stage term reads ``s'``."""
        with torch.no_grad():
            src = state if self.use_action else next_state
            r = self.combine(self.logits(src, action), require(next_state, self.stage_key))
        return r.to(torch.float32)  # the declared reward spec's dtype

    def reward(self, td: TensorDictBase) -> torch.Tensor:
        """Reward of a ``(T,)`` episode (a TensorDict with ``"next"``) or, for a state-only
        classifier, of bare states."""
        if "next" in td.keys():
            return self.reward_of(td, td.get("next"), td.get(self.action_key, None))
        if self.use_action:
            raise KeyError("this reward reads (s, a): pass transitions (with 'next' and 'action'), not bare states")
        return self.reward_of(td, td)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        next_tensordict.set(
            self.reward_key, self.reward_of(tensordict, next_tensordict, tensordict.get(self.action_key, None))
        )
        return next_tensordict

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if "next" in tensordict.keys():
            self._step(tensordict, tensordict.get("next"))
            return tensordict
        tensordict.set(self.reward_key, self.reward(tensordict))
        return tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return tensordict_reset

    def transform_reward_spec(self, reward_spec):
        return bounded_reward_spec(reward_spec, self.reward_key, *self.reward_bounds())

    def reward_bounds(self) -> tuple[float, float]:
        """Smallest and largest reward this transform writes."""
        lo, hi = (F.logsigmoid(torch.tensor(-LOGIT_CLIP)).item(), 0.0) if self.output == "log_sigmoid" else (0.0, 1.0)
        lo, hi = self.classifier_weight * (lo + self.offset), self.classifier_weight * (hi + self.offset)
        if self.stage_weight:
            lo -= self.stage_weight * self.num_stages
        return (min(lo, hi), max(lo, hi))

    # ------------------------------------------------------------ checkpoints
    def description(self) -> dict[str, Any]:
        c = self.classifier
        return {
            "kind": "classifier",
            "method": self.method,
            "num_stages": self.num_stages,
            "in_keys": list(self.reward_in_keys),
            "in_shapes": dict(self.in_shapes),
            "stage_key": self.stage_key,
            "use_action": self.use_action,
            "action_dim": self.action_dim,
            "action_key": self.action_key,
            "output": self.output,
            "offset": self.offset,
            "classifier_weight": self.classifier_weight,
            "stage_weight": self.stage_weight,
            "hidden": list(c.hidden),
            "activation": c.activation,
            "reward_key": self.reward_key,
            "metadata": dict(self.metadata),
        }

    def save(self, path: str | os.PathLike, **extra_metadata) -> Path:
        desc = self.description()
        desc["metadata"].update(extra_metadata)
        return write_reward_checkpoint(path, desc, self.classifier.state_dict())

    @classmethod
    def from_checkpoint(cls, path: str | os.PathLike, map_location="cpu", **overrides) -> "ClassifierReward":
        """Load a reward saved by :meth:`save`; ``overrides`` (e.g. ``stage_weight=``) replace saved settings."""
        payload = read_reward_checkpoint(path, map_location)
        c = dict(payload["config"])
        if c.get("kind") != "classifier":
            raise RewardCheckpointError(f"{path} holds a {c.get('kind', 'drs')!r} reward, not a classifier reward")
        c.update({k: v for k, v in overrides.items() if v is not None})
        c = checkpoint_config(c, path, CLASSIFIER_SETTINGS)
        reward = cls(
            c["in_keys"],
            c["in_shapes"],
            c["num_stages"],
            use_action=c["use_action"],
            action_dim=c["action_dim"],
            action_key=c["action_key"],
            stage_key=c["stage_key"],
            output=c["output"],
            offset=c["offset"],
            classifier_weight=c["classifier_weight"],
            stage_weight=c["stage_weight"],
            hidden=c["hidden"],
            activation=c["activation"],
            reward_key=c["reward_key"],
            method=c["method"],
            metadata=c.get("metadata"),
        )
        load_checked(reward.classifier, payload["state_dict"], path)
        return reward.to(map_location)

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(method={self.method!r}, in_keys={self.reward_in_keys}, use_action={self.use_action}, "
            f"output={self.output!r}, stage_weight={self.stage_weight:.3g})"
        )
