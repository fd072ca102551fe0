"""ManiSkill3 environments as TorchRL envs, and pre-flight checks."""

from drs_torchrl.envs.doctor import (
    CudaUnavailableError,
    MissingAssetError,
    VulkanUnavailableError,
    check_vulkan,
    ensure_env_ready,
)
from drs_torchrl.envs.factory import make_family_env
from drs_torchrl.envs.maniskill import ManiSkillEnv

__all__ = [
    "CudaUnavailableError",
    "ManiSkillEnv",
    "MissingAssetError",
    "VulkanUnavailableError",
    "check_vulkan",
    "ensure_env_ready",
    "make_family_env",
]
