"""Actor and critics of SAC (Appendix E: 3 x 256 MLPs), built from TorchRL modules."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.modules import MLP, BatchRenorm1d, ProbabilisticActor, TanhNormal, ValueOperator

from drs_torchrl.runtime.errors import ConfigError, UserError
from drs_torchrl.runtime.safe_files import UnsafeFileError, torch_load
from drs_torchrl.precision import OutputFloat32

POLICY_FORMAT = "drs-torchrl/policy"  # checkpoints/policy.pt of drs-learn / drs-reuse runs
# what the actor writes besides "action" (the MLP output and the distribution parameters)
POLICY_INTERMEDIATE_KEYS = ("actor_params", "loc", "scale")


class PolicyCheckpointError(UserError, ValueError):
    """A policy checkpoint that cannot be loaded for this env."""


def _in_features(observation_spec, keys: Sequence[str]) -> int:
    missing = [k for k in keys if k not in observation_spec.keys(True, True)]
    if missing:
        raise KeyError(
            f"policy inputs {missing} are not in the observation spec ({list(observation_spec.keys(True, True))})"
        )
    return sum(int(observation_spec[k].shape[-1]) for k in keys)


NORMS = (None, "layer", "batch_renorm")


class AnyBatchRenorm(BatchRenorm1d):
    """TorchRL's ``BatchRenorm1d`` over the last dimension of inputs of any batch shape. Own subclass: TorchRL's
    refuses an unbatched input, which is what a single env's policy call passes; statistics are per feature anyway."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.dim() == 2:
            return super().forward(x)
        return super().forward(x.reshape(-1, x.shape[-1])).reshape(x.shape)


def _norm(kind: str | None, hidden: Sequence[int]) -> dict:
    """TorchRL ``MLP`` arguments for a normalisation after each hidden layer's linear map (before its activation)."""
    if kind not in NORMS:
        raise ConfigError(
            f"algo.critic_norm / algo.actor_norm: unknown normalisation {kind!r}; choose null, layer or batch_renorm"
        )
    if kind is None:
        return {}
    if kind == "batch_renorm":  # CrossQ (Bhatt et al., 2024): running statistics after a warm-up, momentum 0.01
        return {
            "norm_class": AnyBatchRenorm,
            "norm_kwargs": [{"num_features": int(w), "warmup_steps": 100_000} for w in hidden],
        }
    return {"norm_class": nn.LayerNorm, "norm_kwargs": [{"normalized_shape": int(w)} for w in hidden]}


def make_sac_modules(
    observation_spec,
    action_spec,
    in_keys: Sequence[str] = ("observation",),
    hidden: Sequence[int] = (256, 256, 256),
    activation: type[nn.Module] = nn.ReLU,
    device: torch.device | str | None = None,
    return_log_prob: bool = False,
    critic_norm: str | None = None,
    actor_norm: str | None = None,
) -> tuple[ProbabilisticActor, ValueOperator]:
    """A tanh-Gaussian actor and a Q-value network reading ``in_keys`` (+ ``"action"``).

    The actor's distribution is bounded by the action spec; several ``in_keys`` are concatenated
    (the stage indicators can be policy inputs, as in the authors' code). The modules are built on
    ``device`` (default: the spec's device). ``return_log_prob``: the actor also writes its actions' log-probability
    (PPO's importance ratio); the parameters are the same either way, so a policy checkpoint loads into both.
    ``critic_norm`` / ``actor_norm``: ``"layer"`` puts a LayerNorm after every hidden layer's linear map (RLPD, BRO,
    SimBa: the critic's values stay bounded at high update ratios), ``"batch_renorm"`` a BatchRenorm1d (CrossQ; the
    modules then act in eval mode, on running statistics); None: the paper's plain MLPs.
    """
    in_keys = list(in_keys)
    n_obs = _in_features(observation_spec, in_keys)
    n_act = int(action_spec.shape[-1])
    # each MLP ends in a parameterless fp32 cast: under bf16/fp16 autocast only the MLPs' matrix work is
    # low-precision, the distribution, log-probs and losses stay fp32 (drs_torchrl.precision)
    actor_mlp = MLP(
        in_features=n_obs, out_features=2 * n_act, num_cells=list(hidden), activation_class=activation,
        **_norm(actor_norm, hidden),
    )  # fmt: skip
    actor_mlp.append(OutputFloat32())
    actor_net = TensorDictSequential(
        TensorDictModule(
            actor_mlp,
            in_keys=in_keys,
            out_keys=["actor_params"],
        ),
        TensorDictModule(
            NormalParamExtractor(scale_mapping="biased_softplus_1.0", scale_lb=1e-4),
            in_keys=["actor_params"],
            out_keys=["loc", "scale"],
        ),
    )
    actor = ProbabilisticActor(
        actor_net,
        in_keys=["loc", "scale"],
        spec=action_spec,
        distribution_class=TanhNormal,
        distribution_kwargs={"low": action_spec.space.low, "high": action_spec.space.high},
        return_log_prob=return_log_prob,
        default_interaction_type="random",
    )
    qnet = MLP(
        in_features=n_obs + n_act, out_features=1, num_cells=list(hidden), activation_class=activation,
        **_norm(critic_norm, hidden),
    )  # fmt: skip
    qnet.append(OutputFloat32())
    qvalue = ValueOperator(qnet, in_keys=[*in_keys, "action"])
    device = torch.device(device) if device is not None else observation_spec.device or torch.device("cpu")
    actor, qvalue = actor.to(device), qvalue.to(device)
    with torch.no_grad():
        td = observation_spec.zero().to(device)
        actor.eval()  # batch statistics are the loss's business (CrossQ): the modules act on running ones
        qvalue.eval()
        actor(td)
        qvalue(td)
    return actor, qvalue


def resolve_policy_path(path: str | Path) -> Path:
    """``RUN_DIR``, ``RUN_DIR/checkpoints`` or a ``policy.pt`` file -> the ``policy.pt`` path."""
    path = Path(path)
    for cand in (path, path / "policy.pt", path / "checkpoints" / "policy.pt"):
        if cand.is_file():
            return cand
    raise PolicyCheckpointError(
        f"{path}: no policy checkpoint there (expected a drs-learn/drs-reuse run directory "
        "or its checkpoints/policy.pt)"
    )


def read_policy_checkpoint(path: str | Path) -> tuple[Path, dict]:
    """``(file, checkpoint dict)`` of a policy checkpoint (see :func:`resolve_policy_path`), checked for its format."""
    file = resolve_policy_path(path)
    try:
        ck = torch_load(file, "policy checkpoint")
    except UnsafeFileError:
        raise
    except Exception as exc:
        raise PolicyCheckpointError(
            f"{file}: cannot be read as a torch file ({exc.__class__.__name__}: {exc})"
        ) from exc
    if not isinstance(ck, dict) or ck.get("format") != POLICY_FORMAT:
        from drs_torchrl.runtime.rundir import maze_run_message

        if maze := maze_run_message(file.parent):  # the maze's DQN agent: its own format and app
            raise PolicyCheckpointError(f"{file} is the policy of a drs-maze run: {maze}")
        got = ck.get("format") if isinstance(ck, dict) else type(ck).__name__
        raise PolicyCheckpointError(
            f"{file} is not a drs-torchrl policy checkpoint (format {got!r}); pass a run's checkpoints/policy.pt"
        )
    return file, ck


def load_policy(
    path: str | Path, observation_spec, action_spec, *, family: str | None = None
) -> tuple[ProbabilisticActor, dict]:
    """The SAC actor of a ``drs-learn`` / ``drs-reuse`` policy checkpoint, built for the given specs.

    Returns ``(actor, checkpoint metadata)``. Raises :class:`PolicyCheckpointError` (saying what
    does not fit) for a file that is not a policy checkpoint, one from another task family, or one
    whose input/action sizes differ from the env's.
    """
    file, ck = read_policy_checkpoint(path)
    if family is not None and ck.get("family") != family:
        raise PolicyCheckpointError(f"{file} is a policy for family {ck.get('family')!r}, not {family!r}")
    keys = list(ck["policy_in_keys"])
    missing = [k for k in keys if k not in observation_spec.keys(True)]
    if missing:
        raise PolicyCheckpointError(f"{file}: the policy reads {missing}, which this env does not produce")
    try:
        actor, _ = make_sac_modules(observation_spec, action_spec, keys, ck["hidden"], actor_norm=ck.get("actor_norm"))
        actor.load_state_dict(ck["actor"])
    except RuntimeError as exc:  # size mismatches
        sizes = {k: int(observation_spec[k].shape[-1]) for k in keys}
        raise PolicyCheckpointError(
            f"{file} does not fit this env (inputs {sizes}, action {int(action_spec.shape[-1])}): "
            f"{str(exc).splitlines()[0]}"
        ) from exc
    meta = {k: v for k, v in ck.items() if k not in ("actor", "qvalue_params")}
    return actor, meta
