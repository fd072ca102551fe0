"""The DrS learned reward (Sec. 4.2, Eq. 4) as a TorchRL transform.

``R(s') = k + alpha * tanh(D_k(s'))`` where ``k`` is the stage index of the next state ``s'`` and
``D_k`` the discriminator of stage ``k`` ("got beyond stage k" vs "stopped at k or before"). Because
``|tanh| < 1``, any ``alpha < 1/2`` ranks every state of stage ``k+1`` above every state of stage
``k``. At the top stage ``N`` (success) there is no discriminator and the dense term is 0.

Formulas (``formula=``):
    * ``"paper"``: ``k + alpha * tanh(D_k(s'))`` (Eq. 4).
    * ``"rescaled"``: the authors' public code, ``(k + alpha * tanh(D_k(s'))) / N + offset``
      (with alpha = 1/3 and offset = -2 this is ``(3k + tanh(D_k)) / (3N) - 2``).
    * ``"sum"``: the reward-formulation ablation of Appendix F.3, ``sum_k tanh(D_k(s'))``, which
      ignores the stage index (it does not keep the ordering guarantee). It is not shifted: in
      ``(-N, N)``, so where episodes end on success, staying short of it can pay more than reaching it.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.envs.transforms import Transform

from drs_torchrl.runtime.errors import UserError
from drs_torchrl.runtime.rundir import fsync_path
from drs_torchrl.runtime.safe_files import UnsafeFileError, torch_load

CHECKPOINT_FORMAT = "drs-torchrl/reward"
CHECKPOINT_VERSION = 1
FORMULAS = ("paper", "rescaled", "sum")
_ACTIVATIONS = {"sigmoid": nn.Sigmoid, "relu": nn.ReLU, "tanh": nn.Tanh, "elu": nn.ELU}


class RewardCheckpointError(UserError, ValueError):
    """A reward checkpoint that cannot be used: corrupt, foreign, too new, or mismatched."""


class StageDiscriminators(nn.Module):
    """One small MLP per stage ``k = 0..N-1`` (Appendix E.1: one hidden layer of 32 units).

    ``forward(x)`` returns the logits of every discriminator, shape ``(*batch, N)``, so the reward
    of a batch of mixed stages is one pass followed by a gather. ``trained[k]`` records whether
    discriminator ``k`` has taken a training step; an untrained one contributes 0 to the reward, not the
    output of its random initialisation: as in the authors' phase 1, and kept in phase 2 through the
    checkpoint (their reuse script marks every loaded discriminator trained).
    """

    def __init__(
        self, num_stages: int, in_features: int, hidden: Sequence[int] | int = (32,), activation: str = "sigmoid"
    ):
        super().__init__()
        if num_stages < 1:
            raise ValueError("num_stages must be >= 1")
        if activation not in _ACTIVATIONS:
            raise ValueError(f"activation must be one of {sorted(_ACTIVATIONS)}, got {activation!r}")
        hidden = [hidden] if isinstance(hidden, int) else list(hidden)
        self.num_stages, self.in_features, self.hidden, self.activation = num_stages, in_features, hidden, activation

        def mlp() -> nn.Sequential:
            layers, d = [], in_features
            for h in hidden:
                layers += [nn.Linear(d, h), _ACTIVATIONS[activation]()]
                d = h
            layers.append(nn.Linear(d, 1))
            return nn.Sequential(*layers)

        self.nets = nn.ModuleList(mlp() for _ in range(num_stages))
        self.register_buffer("trained", torch.zeros(num_stages, dtype=torch.bool))

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        if "trained" not in state_dict:  # checkpoints written before the flag existed: all trained
            state_dict = {**state_dict, "trained": torch.ones(self.num_stages, dtype=torch.bool)}
        return super().load_state_dict(state_dict, strict=strict, assign=assign)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.cat([net(x) for net in self.nets], dim=-1)

    def stage_logits(self, x: torch.Tensor, k: int) -> torch.Tensor:
        """Logits of discriminator ``k`` only, shape ``(*batch,)``."""
        return self.nets[k](x).squeeze(-1)


def input_sizes(observation_spec, in_keys: Sequence[str]) -> dict[str, int]:
    """The trailing size of each reward input in an env's observation spec (a KeyError naming what it has)."""
    have = list(observation_spec.keys(True, True))
    missing = [k for k in in_keys if k not in have]
    if missing:
        raise KeyError(f"reward input {missing[0]!r} is not in the observation spec; it has {have}")
    return {k: int(observation_spec[k].shape[-1]) for k in in_keys}


class LearnedRewardChecks:
    """``check_compatible`` of a learned reward transform (DrS, the classifier baselines): it reads ``metadata``,
    ``in_shapes``, ``num_stages``, ``stage_key`` and, if it reads actions, ``action_dim``."""

    def check_compatible(
        self,
        observation_spec,
        *,
        num_stages: int | None = None,
        family: str | None = None,
        action_spec=None,
        stage_keys=None,
    ) -> None:
        """Raise :class:`RewardCheckpointError` naming every difference between this reward and an env."""
        problems = compatibility_problems(
            self.metadata,
            self.in_shapes,
            self.num_stages,
            self.stage_key,
            observation_spec,
            num_stages=num_stages,
            family=family,
            action_spec=action_spec,
            action_dim=getattr(self, "action_dim", None),
            stage_keys=stage_keys,
        )
        if problems:
            what = f"the {self.method} reward" if getattr(self, "method", None) else "the reward"
            raise RewardCheckpointError(f"{what} does not fit this environment: " + "; ".join(problems))


class DrSReward(LearnedRewardChecks, Transform):
    """Learned dense reward of DrS (Eq. 4), holding the per-stage discriminators.

    Args:
        num_stages: ``N``, the number of stage indicators (success included).
        in_keys: observation entries the discriminators read (concatenated), e.g.
            ``["observation", "stage_indicators"]``.
        in_shapes: trailing size of each entry of ``in_keys`` (``{key: dim}``).
        stage_key: integer stage index of the state (written by :class:`StageIndicator`).
        formula: ``"paper"``, ``"rescaled"`` or ``"sum"`` (see module docstring).
        alpha: weight of the dense term; ``0 < alpha < 1/2`` keeps the stage ordering.
        offset: constant added by the ``"rescaled"`` formula (public code: -2).
        hidden, activation: discriminator architecture.
        reward_key: where the reward is written.
        metadata: free-form description saved with checkpoints (task family, env id, ...).

    It works inside a :class:`~torchrl.envs.TransformedEnv` (rewards of ``next`` states), as a
    replay-buffer transform (rewards recomputed with the current discriminators at sampling time:
    ``forward`` reads and writes the ``"next"`` sub-TensorDict), and on a bare TensorDict of states.
    The reward is computed without gradients; train the discriminators through
    :attr:`discriminators` (see :class:`~drs_torchrl.objectives.DiscriminatorLoss`).
    """

    def __init__(
        self,
        num_stages: int,
        in_keys: Sequence[str],
        in_shapes: Mapping[str, int],
        *,
        stage_key: str = "stage",
        formula: str = "paper",
        alpha: float = 1.0 / 3.0,
        offset: float = -2.0,
        hidden: Sequence[int] | int = (32,),
        activation: str = "sigmoid",
        reward_key: str = "reward",
        metadata: Mapping[str, Any] | None = None,
    ):
        if formula not in FORMULAS:
            raise ValueError(f"formula must be one of {FORMULAS}, got {formula!r}")
        if formula != "sum" and not 0.0 < alpha < 0.5:
            raise ValueError(
                f"alpha={alpha} breaks the stage ordering of Eq. 4: it must satisfy 0 < alpha < 1/2 "
                "(the paper uses 1/3)."
            )
        in_keys = [k if isinstance(k, str) else tuple(k) for k in in_keys]
        missing = [k for k in in_keys if k not in in_shapes]
        if missing:
            raise ValueError(f"in_shapes lacks the sizes of {missing}")
        super().__init__(in_keys=[*in_keys, stage_key], out_keys=[reward_key])
        self.reward_in_keys = list(in_keys)
        self.in_shapes = {k: int(in_shapes[k]) for k in in_keys}
        self.num_stages = int(num_stages)
        self.stage_key = stage_key
        self.formula = formula
        self.alpha = float(alpha)
        self.offset = float(offset)
        self.reward_key = reward_key
        self.metadata = dict(metadata or {})
        self.discriminators = StageDiscriminators(self.num_stages, sum(self.in_shapes.values()), hidden, activation)

    # ------------------------------------------------------------ reward math
    def features(self, td: TensorDictBase) -> torch.Tensor:
        """Concatenate the reward inputs of states held at the root of ``td``."""
        dtype = next(self.discriminators.parameters()).dtype  # follows .double() / .to(dtype) of the transform
        parts = [require(td, k) for k in self.reward_in_keys]
        for k, x in zip(self.reward_in_keys, parts):  # shapes only: no device sync
            if x.shape[-1:] != (self.in_shapes[k],):
                got = x.shape[-1] if x.dim() else "a scalar"
                raise ValueError(
                    f"the reward reads {k!r} of size {self.in_shapes[k]} (in_shapes), this TensorDict's {k!r} "
                    f"has size {got}"
                )
        return torch.cat([x.to(dtype) for x in parts], dim=-1)

    def combine(self, logits: torch.Tensor, stage: torch.Tensor) -> torch.Tensor:
        """Eq. 4 from all-stage logits ``(*b, N)`` and stage indices ``(*b, 1)``; returns ``(*b, 1)``."""
        if self.formula == "sum":
            return (torch.tanh(logits) * self.discriminators.trained.to(logits.dtype)).sum(-1, keepdim=True)
        k = check_stages(stage, self.num_stages, self.stage_key)
        kd = k.clamp(max=self.num_stages - 1)
        dense = torch.tanh(logits.gather(-1, kd))
        counts = (k < self.num_stages) & self.discriminators.trained.to(k.device)[kd]
        dense = torch.where(counts, dense, torch.zeros_like(dense))
        r = k.to(logits.dtype) + self.alpha * dense
        if self.formula == "rescaled":
            r = r / self.num_stages + self.offset
        return r

    def reward(self, td: TensorDictBase) -> torch.Tensor:
        """Reward of the states at the root of ``td`` (``(*batch, 1)``), without gradients."""
        with torch.no_grad():
            r = self.combine(self.discriminators(self.features(td)), require(td, self.stage_key))
        return r.to(torch.float32)  # the declared reward spec's dtype, whatever the discriminators' dtype

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        next_tensordict.set(self.reward_key, self.reward(next_tensordict))
        return next_tensordict

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if "next" in tensordict.keys():
            self._call(tensordict.get("next"))
            return tensordict
        return self._call(tensordict)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return tensordict_reset

    def transform_reward_spec(self, reward_spec):
        """Declare the reward this transform writes: float32 within :meth:`reward_bounds`."""
        return bounded_reward_spec(reward_spec, self.reward_key, *self.reward_bounds())

    def reward_bounds(self) -> tuple[float, float]:
        """Infimum and maximum of the reward once all discriminators are trained
        (``"paper"``: ``(-alpha, N)``; ``"rescaled"``: ``(offset - alpha/N, offset + 1)``)."""
        N, a = self.num_stages, self.alpha
        if self.formula == "sum":
            return (-float(N), float(N))
        if self.formula == "paper":
            return (-a, float(N))
        return (self.offset - a / N, self.offset + 1.0)

    # ------------------------------------------------------------ construction
    @classmethod
    def from_spec(cls, observation_spec, num_stages: int, in_keys: Sequence[str], **kwargs) -> "DrSReward":
        """Build with input sizes read from an env's observation spec (e.g. ``env.observation_spec``)."""
        return cls(num_stages, in_keys, input_sizes(observation_spec, in_keys), **kwargs)

    @classmethod
    def from_env(cls, env, num_stages: int, in_keys: Sequence[str], **kwargs) -> "DrSReward":
        """A fresh reward for phase 1, sized from ``env``'s specs: the ``model`` builder of ``conf/reward/drs.yaml``
        (every learned reward's ``model`` takes ``(env, num_stages, in_keys, **settings)``)."""
        return cls.from_spec(env.observation_spec, num_stages, in_keys, **kwargs)

    def description(self) -> dict[str, Any]:
        d = self.discriminators
        return {
            "num_stages": self.num_stages,
            "in_keys": list(self.reward_in_keys),
            "in_shapes": dict(self.in_shapes),
            "stage_key": self.stage_key,
            "formula": self.formula,
            "alpha": self.alpha,
            "offset": self.offset,
            "hidden": list(d.hidden),
            "activation": d.activation,
            "reward_key": self.reward_key,
            "normalization": None,
            "metadata": dict(self.metadata),
            "kind": "drs",
        }

    # ------------------------------------------------------------ checkpoints
    def save(self, path: str | os.PathLike, **extra_metadata) -> Path:
        """Write a self-describing checkpoint atomically (a crash never leaves a partial file)."""
        desc = self.description()
        desc["metadata"].update(extra_metadata)
        return write_reward_checkpoint(path, desc, self.discriminators.state_dict())

    @classmethod
    def from_checkpoint(cls, path: str | os.PathLike, map_location: str | torch.device = "cpu") -> "DrSReward":
        """Load a reward saved by :meth:`save`; raises :class:`RewardCheckpointError` with the cause."""
        payload = read_reward_checkpoint(path, map_location)
        if payload["config"].get("kind", "drs") != "drs":
            raise RewardCheckpointError(
                f"{path} holds a {payload['config']['kind']!r} reward, not a DrS reward; load it with load_reward()"
            )
        c = checkpoint_config(
            payload["config"],
            path,
            ("num_stages", "in_keys", "in_shapes", "stage_key", "formula", "alpha", "offset", "hidden", "activation"),
        )
        reward = cls(
            c["num_stages"],
            c["in_keys"],
            c["in_shapes"],
            stage_key=c["stage_key"],
            formula=c["formula"],
            alpha=c["alpha"],
            offset=c["offset"],
            hidden=c["hidden"],
            activation=c["activation"],
            reward_key=c.get("reward_key", "reward"),
            metadata=c.get("metadata"),
        )
        load_checked(reward.discriminators, payload["state_dict"], path)
        return reward.to(map_location)

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(num_stages={self.num_stages}, in_keys={self.reward_in_keys}, "
            f"formula={self.formula!r}, alpha={self.alpha:.4g})"
        )


# ---------------------------------------------------------------- shared by every learned reward
def bounded_reward_spec(reward_spec, key, low: float, high: float):
    """``reward_spec`` with ``key`` declared float32 in ``[low, high]`` (its shape kept)."""
    from torchrl.data import Bounded

    shape = reward_spec[key].shape if key in reward_spec.keys() else (*reward_spec.shape, 1)
    reward_spec[key] = Bounded(low, high, shape=shape, dtype=torch.float32, device=reward_spec.device)
    return reward_spec


def check_stages(stage: torch.Tensor, num_stages: int, key="stage") -> torch.Tensor:
    """``stage`` as int64, or a ValueError naming the labels that are not whole numbers in ``[0, num_stages]``."""
    bad = (stage < 0) | (stage > num_stages)
    if stage.is_floating_point():
        bad |= stage != stage.trunc()  # 0.9 and 2.99 would truncate to 0 and 2; NaN is caught here too
    if bad.any():  # one bool read per call (on a GPU: one device sync); the rest only on the error path
        shown = stage[bad].unique().tolist()
        raise ValueError(
            f"stage labels ({key!r}) must lie in [0, {num_stages}] and be whole numbers, got "
            f"{', '.join(f'{v:g}' for v in shown[:5])}{' ...' if len(shown) > 5 else ''}"
        )
    return stage.to(torch.long)


def require(td: TensorDictBase, key) -> torch.Tensor:
    """``td[key]``, or a KeyError naming the missing reward input and what the TensorDict holds."""
    value = td.get(key, None)
    if value is None:
        raise KeyError(
            f"the reward reads {key!r}, which this TensorDict lacks (it holds {sorted(map(str, td.keys()))})"
        )
    return value


def write_reward_checkpoint(path: str | os.PathLike, config: dict, state_dict: Mapping[str, torch.Tensor]) -> Path:
    """Write ``{format, version, config, state_dict}`` atomically (a crash never leaves a partial file)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "format": CHECKPOINT_FORMAT,
        "version": CHECKPOINT_VERSION,
        "config": config,
        "state_dict": {k: v.detach().cpu() for k, v in state_dict.items()},
    }
    fd, tmp = tempfile.mkstemp(prefix=path.name, suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        torch.save(payload, tmp)
        fsync_path(tmp)  # on the disk before it takes the name
        os.replace(tmp, path)
        fsync_path(path.parent)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def read_reward_checkpoint(path: str | os.PathLike, map_location="cpu") -> dict:
    """The payload of a reward checkpoint; raises :class:`RewardCheckpointError` with the cause."""
    path = Path(path)
    if path.is_dir():
        inside = [f for f in (path / "checkpoints" / "reward.pt", path / "reward.pt") if f.is_file()]
        raise RewardCheckpointError(
            f"reward checkpoint {path} is a directory; pass the file: "
            + (
                f"reward.checkpoint={inside[0]}"
                if inside
                else "the reward.pt that drs-learn wrote (RUN/checkpoints/reward.pt)"
            )
        )
    if not path.is_file():
        raise RewardCheckpointError(
            f"reward checkpoint {path} does not exist (pass reward.checkpoint=PATH to a reward.pt written by drs-learn)"
        )
    try:
        payload = torch_load(path, "reward checkpoint", map_location=map_location)
    except UnsafeFileError:
        raise
    except Exception as exc:
        raise RewardCheckpointError(f"{path} is not a readable checkpoint (corrupt or truncated?): {exc}") from exc
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise RewardCheckpointError(
            f"{path} is not a drs-torchrl reward checkpoint (format={payload.get('format') if isinstance(payload, dict) else type(payload).__name__!r}); "
            "a policy or training-state checkpoint cannot be used as a reward"
        )
    if int(payload.get("version", -1)) > CHECKPOINT_VERSION:
        raise RewardCheckpointError(
            f"{path} has checkpoint format version {payload['version']}, newer than this drs-torchrl "
            f"understands ({CHECKPOINT_VERSION}); upgrade drs-torchrl"
        )
    lacks = [k for k in ("config", "state_dict") if not isinstance(payload.get(k), Mapping)]
    if lacks:
        raise RewardCheckpointError(f"{path} is damaged: it lacks its {' and '.join(lacks)}; learn the reward again")
    return payload


def checkpoint_config(config: Mapping, path, needs: Sequence[str]) -> dict:
    """A copy of a reward checkpoint's saved settings, which must name every one of ``needs``."""
    c = dict(config)
    lacks = [k for k in needs if k not in c]
    if lacks:
        raise RewardCheckpointError(f"{path} is damaged: its settings lack {lacks}; learn the reward again")
    return c


def load_checked(module: nn.Module, state_dict: Mapping[str, torch.Tensor], path) -> None:
    bad = [k for k, v in state_dict.items() if not torch.isfinite(v).all()]
    if bad:
        raise RewardCheckpointError(
            f"{path} holds non-finite (NaN/inf) weights in {bad}: it was saved from a diverged run"
        )
    try:
        module.load_state_dict(state_dict)
    except RuntimeError as exc:
        raise RewardCheckpointError(
            f"{path}: the weights do not match the checkpoint's own description: {exc}"
        ) from exc


def compatibility_problems(
    metadata: Mapping,
    in_shapes: Mapping[str, int],
    num_stages_mine: int,
    stage_key: str | None,
    observation_spec,
    *,
    num_stages=None,
    family=None,
    action_spec=None,
    action_dim: int | None = None,
    stage_keys=None,
) -> list[str]:
    """Every difference between a learned reward's inputs and an env, in words. ``stage_keys``: the env's
    stage indicators, which must be those the reward was learned with (``D_k`` scores "beyond stage k")."""
    problems = []
    mine = metadata.get("family")
    if family is not None and mine is not None and mine != family:
        problems.append(f"it was learned on task family {mine!r}, the env is family {family!r}")
    learned_with = metadata.get("stage_keys")
    hint = f" (it was learned with env.stages=[{','.join(learned_with)}]: pass the same)" if learned_with else ""
    if num_stages is not None and num_stages != num_stages_mine:
        problems.append(f"it has {num_stages_mine} stages, the env's family has {num_stages}{hint}")
    elif stage_keys is not None and learned_with and list(learned_with) != list(stage_keys):
        problems.append(f"its stages are {list(learned_with)}, the env's are {list(stage_keys)}{hint}")
    keys = set(observation_spec.keys(True, True))
    for k, dim in in_shapes.items():
        if k not in keys:
            problems.append(f"it reads {k!r}, which the env does not produce")
        elif int(observation_spec[k].shape[-1]) != dim:
            problems.append(
                f"it reads {k!r} of size {dim}, the env's {k!r} has size {int(observation_spec[k].shape[-1])}"
            )
    if stage_key is not None and stage_key not in keys:
        problems.append(f"it needs the stage index {stage_key!r} (add a StageIndicator transform)")
    if action_dim is not None and action_spec is not None and int(action_spec.shape[-1]) != action_dim:
        problems.append(
            f"it reads actions of size {action_dim}, the env's actions have size {int(action_spec.shape[-1])}"
        )
    return problems


def load_reward(path: str | os.PathLike, map_location="cpu") -> Transform:
    """Any learned reward written by ``drs-learn`` (DrS, or a baseline's classifier), ready to reuse."""
    payload = read_reward_checkpoint(path, map_location)
    kind = payload["config"].get("kind", "drs")
    if kind == "drs":
        return DrSReward.from_checkpoint(path, map_location)
    if kind == "classifier":
        from drs_torchrl.transforms.classifier_reward import ClassifierReward

        return ClassifierReward.from_checkpoint(path, map_location)
    raise RewardCheckpointError(f"{path} holds a reward of kind {kind!r}, which this drs-torchrl does not know")
