"""Where the Hydra configs are: ``conf/`` of a source checkout, ``drs_torchrl/conf`` of an installed wheel, or
``DRS_CONF_DIR``."""

from __future__ import annotations

import os
from pathlib import Path


def conf_dir() -> str:
    env = os.environ.get("DRS_CONF_DIR")
    if env:
        return str(Path(env).resolve())
    here = Path(__file__).resolve()
    for candidate in (here.parent / "conf", *(p / "conf" for p in here.parents)):
        if (candidate / "learn.yaml").is_file():
            return str(candidate)
    raise FileNotFoundError("cannot find drs-torchrl's conf/ directory; set DRS_CONF_DIR=/path/to/conf")


# settings renamed since 0.1.0, old key -> new key: a saved config is read with the new one (apps.cli.resume_config),
# and an override of the old one is refused naming the new one (runtime.console)
RENAMED_SETTINGS = {"reward.disc.updates_per_sac_update": "algo.reward_updates_per_update"}


def renamed_hint(message: str) -> str:
    """``"; KEY is now NEW"`` for each renamed key ``message`` names (empty when it names none)."""
    return "".join(
        f"; {old} is now {new}" for old, new in RENAMED_SETTINGS.items() if old.rpartition(".")[2] in message
    )
