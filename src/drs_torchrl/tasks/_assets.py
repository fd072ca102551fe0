"""Model lists of the asset-backed families, read from the metadata ManiSkill ships in its wheel
(the meshes themselves must be downloaded). Reading them does not import ManiSkill."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path


def partnet_meta(category: str) -> dict:
    """ManiSkill's ``partnet_mobility/meta/info_<category>_train.json`` (model id -> info)."""
    spec = importlib.util.find_spec("mani_skill")
    if spec is None or not spec.submodule_search_locations:
        return {}
    path = (
        Path(next(iter(spec.submodule_search_locations)))
        / "assets"
        / "partnet_mobility"
        / "meta"
        / f"info_{category}_train.json"
    )
    return json.loads(path.read_text()) if path.is_file() else {}
