"""Actor and critics of SAC (Appendix E: 3 x 256 MLPs), built from TorchRL modules."""
from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator


def _in_features(observation_spec, keys: Sequence[str]) -> int:
    missing = [k for k in keys if k not in observation_spec.keys(True, True)]
    if missing:
        raise KeyError(f"policy inputs {missing} are not in the observation spec ({list(observation_spec.keys(True, True))})")
    return sum(int(observation_spec[k].shape[-1]) for k in keys)


def make_sac_modules(
    observation_spec,
    action_spec,
    in_keys: Sequence[str] = ("observation",),
    hidden: Sequence[int] = (256, 256, 256),
    activation: type[nn.Module] = nn.ReLU,
    device: torch.device | str | None = None,
) -> tuple[ProbabilisticActor, ValueOperator]:
    """A tanh-Gaussian actor and a Q-value network reading ``in_keys`` (+ ``"action"``).

    The actor's distribution is bounded by the action spec; several ``in_keys`` are concatenated
    (the stage indicators can be policy inputs, as in the authors' code). The modules are built on
    ``device`` (default: the spec's device).
    """
    in_keys = list(in_keys)
    n_obs = _in_features(observation_spec, in_keys)
    n_act = int(action_spec.shape[-1])
    actor_net = TensorDictSequential(
        TensorDictModule(
            MLP(in_features=n_obs, out_features=2 * n_act, num_cells=list(hidden), activation_class=activation),
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
        return_log_prob=False,
        default_interaction_type="random",
    )
    qnet = MLP(in_features=n_obs + n_act, out_features=1, num_cells=list(hidden), activation_class=activation)
    qvalue = ValueOperator(qnet, in_keys=[*in_keys, "action"])
    device = torch.device(device) if device is not None else observation_spec.device or torch.device("cpu")
    actor, qvalue = actor.to(device), qvalue.to(device)
    with torch.no_grad():
        td = observation_spec.zero().to(device)
        actor(td)
        qvalue(td)
    return actor, qvalue
