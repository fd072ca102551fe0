"""Hydra entry points: ``drs-learn`` (phase 1, reward learning) and ``drs-reuse`` (phase 2).

Configs live in the repository's ``conf/`` (or ``$DRS_CONF_DIR``). Examples::

    drs-learn env=pick_cube algo=sac_cpu total_frames=200000 seed=3
    drs-reuse reward=drs reward.checkpoint=runs/learn/.../checkpoints/reward.pt env.split=test
    drs-reuse reward=dense env.split=test
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig


def conf_dir() -> str:
    env = os.environ.get("DRS_CONF_DIR")
    if env:
        return str(Path(env).resolve())
    here = Path(__file__).resolve()
    for parent in here.parents:
        if (parent / "conf" / "learn.yaml").is_file():
            return str(parent / "conf")
    raise FileNotFoundError("cannot find drs-torchrl's conf/ directory; set DRS_CONF_DIR=/path/to/conf")


def _run(cfg: DictConfig, phase: str) -> None:
    from drs_torchrl.envs.doctor import MissingAssetError, VulkanUnavailableError
    from drs_torchrl.tasks import get_family
    from drs_torchrl.trainers.loop import ConfigError, train
    from drs_torchrl.transforms.reward import RewardCheckpointError

    run_dir = HydraConfig.get().runtime.output_dir
    try:
        get_family(cfg.env.family)
        summary = train(cfg, phase, run_dir)
    except (ConfigError, RewardCheckpointError, MissingAssetError, VulkanUnavailableError, KeyError, ValueError) as exc:
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"drs-{phase}: error: {msg}", file=sys.stderr)
        sys.exit(2)
    ev = summary.get("last_eval", {})
    print(
        f"drs-{phase}: {summary['frames']} env steps, {summary['updates']} SAC updates in "
        f"{summary['wall_time_s']:.0f}s ({summary['env_steps_per_s']:.1f} steps/s); "
        f"eval success {ev.get('success_rate', float('nan')):.2f}; run dir {run_dir}"
    )
    for name, path in summary.get("checkpoints", {}).items():
        print(f"  {name} checkpoint: {path}")


@hydra.main(config_path=conf_dir(), config_name="learn", version_base=None)
def learn_main(cfg: DictConfig) -> None:
    """Phase 1: SAC on the training variants, stage buffers, per-stage discriminators."""
    _run(cfg, "learn")


@hydra.main(config_path=conf_dir(), config_name="reuse", version_base=None)
def reuse_main(cfg: DictConfig) -> None:
    """Phase 2: a fresh SAC agent on held-out variants with a frozen reward (or a baseline)."""
    _run(cfg, "reuse")
