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
