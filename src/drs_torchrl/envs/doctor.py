"""Pre-flight checks: a usable Vulkan device and downloaded ManiSkill assets.

SAPIEN (ManiSkill3's simulator) needs a Vulkan device even for state observations, and ManiSkill
asks interactively on stdin before downloading a missing asset (which dies with ``EOFError`` in a
batch job). Both are checked here first, so a run fails at once with a message naming the fix.
``python -m drs_torchrl.envs.doctor`` (or ``drs-doctor``) runs the checks and steps PickCube once.
"""

from __future__ import annotations

import functools
import sys

from drs_torchrl.runtime.errors import UserError
from drs_torchrl.runtime.console import console_script

VULKAN_HELP = (
    "No usable Vulkan device: SAPIEN (ManiSkill3's simulator) needs one even for state "
    "observations. On a machine with an NVIDIA GPU install its driver with the Vulkan ICD. On a "
    "CPU-only Debian 12 machine install Mesa's software driver (lavapipe) from backports, as root:\n"
    "  echo 'deb http://deb.debian.org/debian bookworm-backports main' "
    "> /etc/apt/sources.list.d/backports.list\n"
    "  apt-get update && apt-get install -y -t bookworm-backports mesa-vulkan-drivers libvulkan1\n"
    "(bin/setup.sh does this for you). Debian 12's own Mesa 22.3 is too old."
)

# asset groups of envs whose ManiSkill registration does not list them
_EXTRA_ASSETS = {
    "OpenCabinetDoor-v1": "partnet_mobility_cabinet",
    "OpenCabinetDrawer-v1": "partnet_mobility_cabinet",
}

# drs-torchrl's asset-backed family envs (envs/variants/assets.py): env id -> (ManiSkill download id,
# data-source id of one model, or None when one download holds every model). Only the models of the
# variants an env is given must be on disk.
_SPLIT_ASSETS = {
    "PickSingleYCBSplit-v1": ("ycb", None),
    "TurnFaucetSplit-v1": ("partnet_mobility_faucet", "partnet_mobility/{}"),
    "OpenCabinetDoorSplit-v1": ("partnet_mobility_cabinet", "partnet_mobility/{}"),
}


class MissingAssetError(UserError, RuntimeError):
    """A ManiSkill asset the environment needs is not downloaded."""


class VulkanUnavailableError(UserError, RuntimeError):
    """SAPIEN found no Vulkan device."""


class CudaUnavailableError(UserError, RuntimeError):
    """The config asks for CUDA (GPU simulation or learner) on a machine without it."""


@functools.lru_cache(maxsize=1)
def check_vulkan() -> str:
    """Return SAPIEN's render-device summary; raise :class:`VulkanUnavailableError` if none."""
    try:
        import sapien

        summary = sapien.render.get_device_summary()
        sapien.render.RenderSystem()  # what building any actor needs
    except Exception as exc:  # SAPIEN raises RuntimeError("failed to find a rendering device")
        raise VulkanUnavailableError(f"{VULKAN_HELP}\n(SAPIEN said: {exc})") from exc
    return summary


def _asset_groups(env_id: str, env_kwargs: dict | None) -> list[str]:
    """ManiSkill download ids (data groups or sources) that ``env_id`` and its robot use."""
    kwargs = env_kwargs or {}
    if env_id in _SPLIT_ASSETS:
        groups = [_SPLIT_ASSETS[env_id][0]]
    else:
        groups = [env_id] + ([_EXTRA_ASSETS[env_id]] if env_id in _EXTRA_ASSETS else [])
    robots = {kwargs.get("robot_uids")} | {v.get("robot_uids") for v in kwargs.get("variants") or []}
    groups += sorted(r for r in robots if isinstance(r, str))
    return groups


def missing_assets(env_id: str, env_kwargs: dict | None = None) -> list[str]:
    """ManiSkill data-source ids that ``env_id`` (and its robot) need and that are not on disk.

    For drs-torchrl's split envs only the models named by the variants in ``env_kwargs`` count.
    """
    from mani_skill.utils.assets import data

    def expand(group):
        try:
            return list(data.expand_data_group_into_individual_data_source_ids(group))
        except Exception:
            return [group] if group in data.DATA_SOURCES else []

    needed: list[str] = []
    for group in _asset_groups(env_id, env_kwargs):
        if env_id in _SPLIT_ASSETS and group == _SPLIT_ASSETS[env_id][0] and _SPLIT_ASSETS[env_id][1]:
            models = [
                m for v in (env_kwargs or {}).get("variants") or [env_kwargs or {}] for m in v.get("model_ids") or []
            ]
            if models:
                needed += [_SPLIT_ASSETS[env_id][1].format(m) for m in models]
                continue
        needed += expand(group)
    return sorted({i for i in needed if i not in data.DATA_SOURCES or not data.is_data_source_downloaded(i)})


def asset_download_command(env_id: str, env_kwargs: dict | None = None) -> str:
    from mani_skill.utils.assets import data

    ids = [g for g in _asset_groups(env_id, env_kwargs) if g in data.DATA_GROUPS or g in data.DATA_SOURCES]
    return " && ".join(f"python -m mani_skill.utils.download_asset {i} -y" for i in ids)


def ensure_env_ready(env_id: str, env_kwargs: dict | None = None) -> None:
    """Fail fast (never on ManiSkill's interactive prompt) if ``env_id`` cannot run here."""
    check_vulkan()
    missing = missing_assets(env_id, env_kwargs)
    if missing:
        shown = ", ".join(missing[:5]) + (f" and {len(missing) - 5} more" if len(missing) > 5 else "")
        raise MissingAssetError(
            f"{env_id} needs ManiSkill assets that are not downloaded: {shown}. Download them with:\n"
            f"  {asset_download_command(env_id, env_kwargs)}\n"
            "(set MS_ASSET_DIR to keep them elsewhere than ~/.maniskill/data)."
        )


@console_script("drs-doctor")
def main(argv: list[str] | None = None) -> int:
    """Print the render device and step PickCube once; a missing Vulkan device or asset ends in one line
    with the fix (exit 2, through the console-script wrapper)."""
    print("render device:", check_vulkan().strip().splitlines()[0] if check_vulkan().strip() else "?")
    from drs_torchrl.envs.maniskill import ManiSkillEnv

    env = ManiSkillEnv("PickCube-v1", ("is_grasped", "success"))
    env.set_seed(0)
    td = env.rand_step(env.reset())
    env.close()
    print("PickCube-v1 stepped:", tuple(td["next", "observation"].shape))
    print(family_asset_report())
    return 0


def family_asset_report() -> str:
    """One line per ManiSkill task family: ready, or the assets it lacks and the command that fetches them."""
    from drs_torchrl.tasks import get_family, list_families

    lines = ["task families:"]
    for name in list_families():
        fam = get_family(name)
        if getattr(fam, "backend", "maniskill") != "maniskill":
            continue
        needs = []
        for split in ("train", "test"):
            args = fam.env_args(split)
            if missing_assets(args["env_id"], args["env_kwargs"]):
                needs.append(asset_download_command(args["env_id"], args["env_kwargs"]))
        status = "ready" if not needs else "needs assets: " + " ; ".join(dict.fromkeys(needs))
        lines.append(f"  {name:<18} {status}")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
