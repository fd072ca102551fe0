"""The reward registry, ``conf/reward/``: a reward exists when ``conf/reward/<name>.yaml`` does, and that file names
what builds it (``slot``, ``model``, ``learner``, ``reuses``; :mod:`drs_torchrl.rewards`). Read here, by the apps, so that the
library below them reads no config folder: it builds a reward from the config node it is given."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig, OmegaConf, open_dict

from drs_torchrl.config_dir import conf_dir

__all__ = ["available_rewards", "registry_entry", "with_builders"]

BUILDER_KEYS = ("slot", "model", "learner", "reuses", "trains_on")


def available_rewards() -> list[str]:
    """Every reward of the registry (the files of ``conf/reward/``)."""
    return sorted(p.stem for p in (Path(conf_dir()) / "reward").glob("*.yaml"))


def registry_entry(name: str) -> DictConfig:
    """``conf/reward/<name>.yaml`` over the entries its ``defaults`` list names (``gail_stages`` over ``gail``), as
    Hydra composes it; a ValueError naming the choices for a name the registry does not hold."""
    path = Path(conf_dir()) / "reward" / f"{name}.yaml"
    if not path.is_file():
        raise ValueError(f"unknown reward {name!r}; choose one of {available_rewards()} (conf/reward/)")
    own = OmegaConf.load(path)
    bases = [registry_entry(str(d)) for d in own.pop("defaults", []) if d != "_self_"]
    return OmegaConf.merge(*bases, own) if bases else own


def with_builders(reward: DictConfig) -> DictConfig:
    """``reward`` (a ``reward`` config node) with its registry entry's builder keys where it lacks them: a config
    saved before the registry named builders, or the maze's inline ``reward`` (its name only). A learned reward saved
    before its entry named a ``model`` (0.1.x: ``learner`` was a ``drs_torchrl.rewards.*_learner`` function) gets the
    entry's ``model`` and ``learner``, whose settings link to the node's own. Changed in place and returned; a
    node that names its builders is returned as it is."""
    if reward.get("name") is None:  # (nothing to look up without a name)
        return reward
    stale = reward.get("learner") is not None and reward.get("model") is None
    if reward.get("slot") is not None and (not stale or str(reward.name) not in available_rewards()):
        return reward  # (a stale reward of the user's own: its builders are theirs)
    entry = registry_entry(str(reward.name))
    with open_dict(reward):
        for key in BUILDER_KEYS:
            if entry.get(key) is not None and (reward.get(key) is None or (stale and key == "learner")):
                reward[key] = entry[key]
    return reward
