"""Checks of a drs-learn / drs-reuse config before anything is built: the schema's types and ranges
(``apps/schema.py``), then the rules between fields that a schema cannot express; and the collector choice that
depends on the device."""

from __future__ import annotations

import torch
from hydra.utils import get_class
from omegaconf import DictConfig, OmegaConf
from torchrl.collectors import MultiCollector

from drs_torchrl.apps.overrides import check_constructor_arguments
from drs_torchrl.apps.schema import RunSchema, check
from drs_torchrl.data.demo_mix import requested_sac_share
from drs_torchrl.runtime.errors import ConfigError
from drs_torchrl.rewards import stage_buffers_hold_demos
from drs_torchrl.updaters.sac import compile_scope
from drs_torchrl.transforms.reward import _ACTIVATIONS, FORMULAS

__all__ = ["ConfigError", "validate_config", "collects_in_background", "collector_for_device"]


def collects_in_background(collector: DictConfig) -> bool:
    """True when the ``algo.collector`` node steps the env in its own process (TorchRL's ``AsyncCollector``/
    ``MultiAsyncCollector``/``MultiSyncCollector``), overlapping simulation with the updates of this process."""
    return issubclass(get_class(collector._target_), MultiCollector)


def collector_for_device(collector: DictConfig, device: torch.device) -> tuple[DictConfig, str | None]:
    """The ``algo.collector`` node to use on ``device`` and the console note: on a GPU, the in-process ``Collector``
    replaces a background one (``AsyncCollector``/``Multi*``: the CPU-machine speed choice of ``algo=sac_cpu``, whose
    worker cannot feed a CUDA learner); otherwise the node as it is and None. ``collector`` itself is not changed."""
    if torch.device(device).type == "cpu" or not collects_in_background(collector):
        return collector, None
    chosen = OmegaConf.create(OmegaConf.to_container(collector, resolve=True))  # standalone: no ${algo...} links
    chosen._target_ = "torchrl.collectors.Collector"
    chosen.pop("num_workers", None)
    return chosen, (
        f"device={torch.device(device).type}: the in-process torchrl.collectors.Collector replaces "
        f"algo.collector={collector._target_} (a background worker cannot feed a GPU learner)"
    )


def validate_config(cfg: DictConfig, phase: str, resume: bool = False) -> None:
    """Reject values that would fail later or silently do nothing (``resume``: ``cfg`` is a run's saved config)."""
    if "map" in cfg and cfg.env.get("family") is None:  # conf/env/maze.yaml composed into drs-learn's config
        raise ConfigError(
            "env=maze is run by drs-maze (conf/maze.yaml): a drs-learn/drs-reuse command line with env=maze hands it "
            "over by itself, but a composed drs-learn config (a study's check, a multirun) cannot hold it; run "
            "drs-maze phase=learn|reuse ... instead"
        )
    if cfg.algo.get("name") == "dqn":  # conf/algo/dqn.yaml: a discrete-action agent
        raise ConfigError(
            "algo=dqn acts on discrete actions: it runs the maze (drs-learn env=maze algo=dqn, or drs-maze); this "
            "family's actions are continuous: use algo=sac_cpu (the default), sac_paper, crossq, ppo, ..."
        )
    check(cfg, RunSchema)
    check_constructor_arguments(cfg)
    a = cfg.algo
    checks = [
        (
            a.get("buffer_size", a.batch_size) >= a.batch_size,  # off-policy algorithms' replay buffer
            f"algo.buffer_size ({a.get('buffer_size')}) is smaller than algo.batch_size ({a.batch_size})",
        ),
        (phase in ("learn", "reuse"), f"phase must be learn or reuse, got {phase}"),
        (
            # without a replay buffer the algorithm is on-policy: the collector's random warm-up steps carry no
            # log-probabilities of its policy, and PPO's ratios would read stale ones
            "buffer_size" in a or int(a.get("learning_starts", 0)) == 0,
            f"algo.learning_starts must be 0 for algo={a.get('name')} (on-policy: it trains on what its own policy "
            f"collected), got {a.get('learning_starts')}",
        ),
    ]
    r, e = cfg.reward, cfg.env
    for key, value, allowed in (
        ("reward.formula", r.get("formula"), FORMULAS),
        ("reward.activation", r.get("activation"), tuple(_ACTIVATIONS)),
        ("env.cpu_batching", e.get("cpu_batching"), ("serial", "parallel")),
    ):
        checks.append((value is None or value in allowed, f"{key} must be one of {', '.join(allowed)}, got {value!r}"))
    for ok, msg in checks:
        if not ok:
            raise ConfigError(msg)
    requested_sac_share((cfg.get("demos") or {}).get("sac_share"))
    try:
        compile_scope(a.get("compile"))
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    stage_buffers = (cfg.get("demos") or {}).get("stage_buffers", True)
    if stage_buffers not in (True, False, "auto"):
        raise ConfigError(f"demos.stage_buffers must be true, false or auto, got {stage_buffers!r}")
    if stage_buffers is False and (phase != "learn" or not stage_buffers_hold_demos(cfg.reward)):
        raise ConfigError(
            "demos.stage_buffers=false is for drs-learn reward=drs (the demonstrations in the SAC batch "
            f"only); this run is drs-{phase} reward={cfg.reward.name}"
        )
    demos = cfg.get("demos") or {}
    # settings of demonstrations, with none to set (a run's saved config holds the stage_buffers that auto chose)
    for key, unset in (("num", None), ("stage_buffers", "auto")):
        if key == "stage_buffers" and (resume or cfg.get("resume")):
            continue
        if not demos.get("path") and demos.get(key, unset) != unset:
            given = str(demos.get(key)).lower() if isinstance(demos.get(key), bool) else demos.get(key)
            raise ConfigError(
                f"demos.{key}={given} is a setting of the demonstrations in demos.path, which is not set: "
                f"name them with demos.path=DIR (made by drs-demos), or drop demos.{key}"
            )
    if cfg.logger.get("wandb", False):
        import importlib.util

        if importlib.util.find_spec("wandb") is None:
            raise ConfigError(
                "logger.wandb=true needs the wandb package: pip install wandb (or set logger.wandb=false)"
            )
        if cfg.logger.get("wandb_mode", "offline") not in ("offline", "online"):
            raise ConfigError(f"logger.wandb_mode must be offline or online, got {cfg.logger.wandb_mode!r}")
    if cfg.device not in ("cpu", "auto") and not str(cfg.device).startswith("cuda"):
        raise ConfigError(f"device must be cpu, cuda[:i] or auto, got {cfg.device}")
    if str(cfg.device).startswith("cuda") and not torch.cuda.is_available():
        raise ConfigError(f"device={cfg.device} was requested but CUDA is not available; use device=cpu")
