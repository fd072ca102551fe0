"""Hydra entry points: ``drs-learn`` (phase 1, reward learning) and ``drs-reuse`` (phase 2).

Configs live in the repository's ``conf/`` (or ``$DRS_CONF_DIR``). Examples::

    drs-learn env=pick_cube algo=sac_cpu total_frames=200000 seed=3
    drs-reuse reward=drs reward.checkpoint=runs/learn/.../checkpoints/reward.pt env.split=test
    drs-reuse reward=dense env.split=test
    drs-learn resume=runs/learn/pick_cube/drs/<run>          # continue an interrupted run
    drs-learn resume=runs/learn/pick_cube/drs/<run> total_frames=2000000   # ... and extend it
"""
from __future__ import annotations

import os
import shutil
import sys
from datetime import datetime
from pathlib import Path

import hydra
import yaml
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

GROUPS = ("env", "reward", "algo", "logger")


def _run_dir_resolver(resume, default):
    return str(resume) if resume else default


_STARTED = datetime.now().strftime("%Y%m%d-%H%M%S")  # one stamp per process: resolvers run more than once


def _hydra_subdir_resolver(resume):
    return ".hydra-resume-" + _STARTED if resume else ".hydra"


OmegaConf.register_new_resolver("drs_run_dir", _run_dir_resolver, replace=True)
OmegaConf.register_new_resolver("drs_hydra_subdir", _hydra_subdir_resolver, replace=True)


class ResumeError(ValueError):
    """``resume=RUN_DIR`` that cannot be honoured."""


def resume_config(run_dir: Path, phase: str, overrides: list[str], composed: DictConfig | None = None) -> DictConfig:
    """The saved config of ``run_dir`` with this invocation's value overrides applied on top
    (values as Hydra parsed them into ``composed``, when given)."""
    saved_path = run_dir / "config.yaml"
    if not saved_path.is_file():
        raise ResumeError(f"cannot resume: {run_dir} is not a drs-torchrl run directory (no config.yaml)")
    saved = OmegaConf.load(saved_path)
    if saved.get("phase") != phase:
        raise ResumeError(f"{run_dir} is a drs-{saved.get('phase')} run; resume it with drs-{saved.get('phase')}")
    for o in overrides:
        key, _, value = o.partition("=")
        adding = key.startswith("+") and not key.startswith("++")
        key = key.lstrip("+~")
        if key == "resume" or key.startswith("hydra."):
            continue
        if key in GROUPS:
            raise ResumeError(f"cannot switch config group {key!r} of a run being resumed; start a new run instead")
        if OmegaConf.select(saved, key, default="__missing__") == "__missing__":
            parent = key.rpartition(".")[0]
            # "+key=value" may add an entry to a free-form mapping the run has (e.g. env.variant_overrides)
            if not (adding and parent and isinstance(OmegaConf.select(saved, parent, default=None), DictConfig)):
                raise ResumeError(f"override {key!r} does not exist in the config of {run_dir}")
        parsed = OmegaConf.select(composed, key) if composed is not None else yaml.safe_load(value)
        OmegaConf.update(saved, key, parsed, merge=True)
    saved.resume = str(run_dir)
    return saved


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
    from drs_torchrl.envs.doctor import CudaUnavailableError, MissingAssetError, VulkanUnavailableError
    from drs_torchrl.tasks import get_family
    from drs_torchrl.trainers.loop import ConfigError, NonFiniteError, TrainingStateError, train
    from drs_torchrl.transforms.reward import RewardCheckpointError

    run_dir = HydraConfig.get().runtime.output_dir
    record = Path(run_dir) / HydraConfig.get().output_subdir if HydraConfig.get().output_subdir else None
    try:
        resume = bool(cfg.get("resume"))
        if resume:
            run_dir = str(Path(cfg.resume))
            cfg = resume_config(Path(run_dir), phase, list(HydraConfig.get().overrides.task), composed=cfg)
        get_family(cfg.env.family)
        summary = train(cfg, phase, run_dir, resume=resume)
    except (ConfigError, RewardCheckpointError, MissingAssetError, VulkanUnavailableError, CudaUnavailableError, TrainingStateError,
            ResumeError, KeyError, ValueError) as exc:
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"drs-{phase}: error: {msg}", file=sys.stderr)
        if record is not None and record.name.startswith(".hydra-resume-"):
            shutil.rmtree(record, ignore_errors=True)  # a failed resume leaves the run as it was
            try:
                record.parent.rmdir()  # only if Hydra made it for a path that was not a run
            except OSError:
                pass
        sys.exit(2)
    except NonFiniteError as exc:
        print(f"drs-{phase}: stopped: {exc}", file=sys.stderr)
        sys.exit(3)
    if summary.get("interrupted"):
        print(f"drs-{phase}: interrupted at {summary['frames']} env steps; continue with: drs-{phase} resume={run_dir}")
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
