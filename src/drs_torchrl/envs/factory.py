"""Build the TorchRL env of a task family variant: ManiSkill env + stage labelling (+ reward)."""
from __future__ import annotations

from collections.abc import Sequence

from torchrl.envs import TransformedEnv
from torchrl.envs.transforms import Transform

from drs_torchrl.envs.maniskill import ManiSkillEnv
from drs_torchrl.tasks import TaskFamily
from drs_torchrl.transforms.stages import StageIndicator


def make_family_env(
    family: TaskFamily,
    variant: str = "train",
    *,
    variant_overrides: dict | None = None,
    reward_mode: str = "sparse",
    semi_sparse_reward: bool = False,
    semi_sparse_offset: float | None = None,
    sim_backend: str = "physx_cpu",
    num_envs: int = 1,
    control_mode: str | None = None,
    max_episode_steps: int | None = None,
    transforms: Sequence[Transform] = (),
    seed: int | None = None,
) -> TransformedEnv:
    """A :class:`~torchrl.envs.TransformedEnv` for ``variant`` of ``family``.

    The base env writes the family's indicators; :class:`StageIndicator` adds ``"stage"`` and
    ``"stage_indicators"``; ``transforms`` (e.g. a frozen :class:`DrSReward`) come after it.
    """
    base = ManiSkillEnv(
        family.env_id,
        family.all_info_keys,
        num_envs=num_envs,
        sim_backend=sim_backend,
        control_mode=control_mode or family.control_mode,
        reward_mode=reward_mode,
        max_episode_steps=max_episode_steps or family.max_episode_steps,
        env_kwargs=family.variant_kwargs(variant, variant_overrides),
    )
    env = TransformedEnv(base, StageIndicator(
            family.stage_keys,
            semi_sparse_reward=semi_sparse_reward,
            semi_sparse_offset=-family.num_stages if semi_sparse_offset is None else semi_sparse_offset,
        ),
    )
    for t in transforms:
        env.append_transform(t)
    if seed is not None:
        env.set_seed(seed)
    return env
