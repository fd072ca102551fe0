"""The reward registry, ``conf/reward/``: a reward exists when ``conf/reward/<name>.yaml`` does, and that file names
what builds it (``slot``, ``learner``, ``reuses``; :mod:`drs_torchrl.rewards`). Read here, by the apps, so that the
library below them reads no config folder: it builds a reward from the config node it is given."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig, OmegaConf, open_dict

from drs_torchrl.config_dir import conf_dir

__all__ = ["available_rewards", "registry_entry", "with_builders"]

BUILDER_KEYS = ("slot", "learner", "reuses", "trains_on")


def available_rewards() -> list[str]:
    """Every reward of the registry (the files of ``conf/reward/``)."""
    return sorted(p.stem for p in (Path(conf_dir()) / "reward").glob("*.yaml"))


def registry_entry(name: str) -> DictConfig:
    """``conf/reward/<name>.yaml``; a ValueError naming the choices for a name the registry does not hold."""
    path = Path(conf_dir()) / "reward" / f"{name}.yaml"
    if not path.is_file():
        raise ValueError(f"unknown reward {name!r}; choose one of {available_rewards()} (conf/reward/)")
    return OmegaConf.load(path)


def with_builders(reward: DictConfig) -> DictConfig:
    """``reward`` (a ``reward`` config node) with its registry entry's builder keys where it lacks them: a config
    saved before the registry named builders, or the maze's inline ``reward`` (its name only). Changed in place and
    returned; a node that names its ``slot`` is returned as it is."""
    if reward.get("slot") is not None or reward.get("name") is None:  # (nothing to look up without a name)
        return reward
    entry = registry_entry(str(reward.name))
    with open_dict(reward):
        for key in BUILDER_KEYS:
            if entry.get(key) is not None and reward.get(key) is None:
                reward[key] = entry[key]
    return reward
