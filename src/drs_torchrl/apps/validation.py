"""Checks of a drs-learn / drs-reuse config before anything is built: types of the numeric settings, ranges,
and the cross-field rules a schema cannot express; and the collector choice that depends on the device."""

from __future__ import annotations

import torch
from hydra.utils import get_class
from omegaconf import DictConfig, OmegaConf, open_dict
from torchrl.collectors import MultiCollector

from drs_torchrl.data.demo_mix import requested_sac_share
from drs_torchrl.errors import ConfigError
from drs_torchrl.rewards import is_learned

__all__ = ["ConfigError", "validate_config", "collects_in_background", "collector_for_device"]


# numeric settings and their types: a value of another type (``total_frames=abc``) is refused by name
# before anything compares or computes with it
_NUMERIC = {
    "total_frames": int,
    "seed": int,
    "checkpoint_interval": int,
    "torch_threads": (int, type(None)),
    "eval.interval": int,
    "eval.episodes": int,
    "eval.episode_seed": (int, type(None)),
    "logger.interval": int,
    "logger.episode_window": int,
    "algo.batch_size": int,
    "algo.frames_per_batch": int,
    "algo.learning_starts": int,
    "algo.buffer_size": int,
    "algo.utd": (int, float),
    "algo.epochs": int,
    "algo.gamma": (int, float),
    "algo.tau": (int, float),
    "reward.alpha": (int, float),
    "reward.stage_buffer_size": int,
    "reward.disc.batch_size": int,
    "reward.disc.lr": (int, float),
    "reward.disc.updates_per_sac_update": (int, float),
    "reward.disc.window": int,
    "reward.disc.early_stop_threshold": (int, float, type(None)),
}


def _check_types(cfg: DictConfig) -> None:
    for key, types in _NUMERIC.items():
        value = OmegaConf.select(cfg, key, default="__absent__")
        if isinstance(value, str) and value == "__absent__":
            continue
        if isinstance(value, bool) or not isinstance(value, types):
            kinds = types if isinstance(types, tuple) else (types,)
            want = " or ".join(
                "null" if t is type(None) else ("a number" if t is float else "an integer")
                for t in kinds
                if not (t is int and float in kinds)
            )
            raise ConfigError(
                f"{key} must be {want}, got {value!r} ({type(value).__name__}); e.g. {key}={_EXAMPLES.get(key, 1)}"
            )


_EXAMPLES = {
    "total_frames": 200000,
    "algo.gamma": 0.8,
    "algo.tau": 0.005,
    "algo.utd": 0.5,
    "reward.alpha": 0.3333,
    "reward.disc.lr": 0.0003,
    "algo.batch_size": 256,
    "seed": 0,
}


def collects_in_background(cfg: DictConfig) -> bool:
    """True when ``algo.collector`` steps the env in its own process (TorchRL's ``AsyncCollector``/
    ``MultiAsyncCollector``/``MultiSyncCollector``), overlapping simulation with the updates of this process."""
    return issubclass(get_class(cfg.algo.collector._target_), MultiCollector)


def collector_for_device(cfg: DictConfig, device: torch.device) -> str | None:
    """On a GPU, replace a background collector (``AsyncCollector``/``Multi*``: the CPU-machine speed choice of
    ``algo=sac_cpu``, whose worker cannot feed a CUDA learner) by the in-process ``Collector``; returns the
    console note, or None when nothing changed. Edits ``cfg`` (saved in config.yaml: a resume keeps it)."""
    target = cfg.algo.collector._target_
    if torch.device(device).type == "cpu" or not collects_in_background(cfg):
        return None
    with open_dict(cfg):
        cfg.algo.collector._target_ = "torchrl.collectors.Collector"
        cfg.algo.collector.pop("num_workers", None)
    return (
        f"device={torch.device(device).type}: the in-process torchrl.collectors.Collector replaces "
        f"algo.collector={target} (a background worker cannot feed a GPU learner)"
    )


def validate_config(cfg: DictConfig, phase: str) -> None:
    """Reject values that would fail later or silently do nothing."""
    _check_types(cfg)
    a = cfg.algo
    checks = [
        (cfg.total_frames > 0, f"total_frames must be > 0, got {cfg.total_frames}"),
        (a.batch_size > 0, f"algo.batch_size must be > 0, got {a.batch_size}"),
        (a.frames_per_batch > 0, f"algo.frames_per_batch must be > 0, got {a.frames_per_batch}"),
        (a.get("utd", 1) > 0, f"algo.utd must be > 0, got {a.get('utd')}"),
        (0 < a.gamma <= 1, f"algo.gamma must be in (0, 1], got {a.gamma}"),
        (a.learning_starts >= 0, f"algo.learning_starts must be >= 0, got {a.learning_starts}"),
        (
            a.get("buffer_size", a.batch_size) >= a.batch_size,  # off-policy algorithms' replay buffer
            f"algo.buffer_size ({a.get('buffer_size')}) is smaller than algo.batch_size ({a.batch_size})",
        ),
        (a.get("epochs", 1) > 0, f"algo.epochs must be > 0, got {a.get('epochs')}"),
        (cfg.eval.episodes >= 0 and cfg.eval.interval > 0, "eval.episodes must be >= 0 and eval.interval > 0"),
        (
            cfg.eval.get("episode_seed") is None or cfg.eval.episode_seed >= 0,
            f"eval.episode_seed must be null or >= 0, got {cfg.eval.get('episode_seed')}",
        ),
        (phase in ("learn", "reuse"), f"phase must be learn or reuse, got {phase}"),
    ]
    if phase == "learn" and is_learned(cfg.reward):
        checks.append((cfg.reward.disc.batch_size > 0, "reward.disc.batch_size must be > 0"))
        checks.append(
            (
                cfg.reward.disc.updates_per_sac_update > 0,
                f"reward.disc.updates_per_sac_update must be > 0 (fractions allowed, e.g. 0.5), got {cfg.reward.disc.updates_per_sac_update}",
            )
        )
    for ok, msg in checks:
        if not ok:
            raise ConfigError(msg)
    requested_sac_share((cfg.get("demos") or {}).get("sac_share"))
    stage_buffers = (cfg.get("demos") or {}).get("stage_buffers", True)
    if stage_buffers not in (True, False, "auto"):
        raise ConfigError(f"demos.stage_buffers must be true, false or auto, got {stage_buffers!r}")
    if stage_buffers is False and (phase != "learn" or cfg.reward.name != "drs"):
        raise ConfigError(
            "demos.stage_buffers=false is for drs-learn reward=drs (the demonstrations in the SAC batch "
            f"only); this run is drs-{phase} reward={cfg.reward.name}"
        )
    stop = cfg.get("stop_at_success")
    if stop is not None and (isinstance(stop, bool) or not isinstance(stop, (int, float)) or not 0 <= stop <= 1):
        raise ConfigError(
            f"stop_at_success must be null or a success rate in [0, 1], got {stop!r}; e.g. stop_at_success=0.8"
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
