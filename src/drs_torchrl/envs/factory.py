"""Build the TorchRL env of a task family variant: ManiSkill env + stage labelling (+ reward)."""

from __future__ import annotations

import functools
from collections.abc import Sequence

import torch
from torchrl.envs import ParallelEnv, SerialEnv, TransformedEnv
from torchrl.envs.transforms import RewardScaling, Transform

from drs_torchrl.envs.maniskill import ManiSkillEnv
from drs_torchrl.tasks import TaskFamily
from drs_torchrl.transforms.stages import SemiSparseReward, StageIndicator


def make_family_env(
    family: TaskFamily,
    variant: str = "train",
    *,
    variant_overrides: dict | None = None,
    reward_mode: str = "sparse",
    semi_sparse_reward: bool = False,
    semi_sparse_offset: float | None = None,
    reward_offset: float = 0.0,
    sim_backend: str = "physx_cpu",
    num_envs: int = 1,
    control_mode: str | None = None,
    max_episode_steps: int | None = None,
    transforms: Sequence[Transform] = (),
    seed: int | None = None,
    cpu_batching: str = "serial",
    render_mode: str | None = None,
) -> TransformedEnv:
    """A :class:`~torchrl.envs.TransformedEnv` for ``variant`` of ``family``.

    The base env writes the family's indicators; :class:`StageIndicator` adds ``"stage"`` and
    ``"stage_indicators"``; ``reward_offset`` (if not 0) shifts the env's reward with TorchRL's
    :class:`~torchrl.envs.transforms.RewardScaling`; ``transforms`` (e.g. a frozen :class:`DrSReward`) come after.
    ``num_envs > 1`` on the CPU backend batches that many single-env simulators with TorchRL's
    :class:`~torchrl.envs.SerialEnv` (``cpu_batching="serial"``) or
    :class:`~torchrl.envs.ParallelEnv` (``"parallel"``, one process each); on the GPU backend
    ManiSkill simulates them all in one process.
    """
    # a pooled family's env gets every variant of the split and draws one per episode (tasks/__init__.py)
    args = family.env_args(variant, variant_overrides)
    env_id = args["env_id"]
    # variants with their own episode length (``max_steps``, e.g. turn_valve's levels) end their episodes
    # themselves; the env's time limit must let the longest one run
    pool = args["env_kwargs"].get("variants") or [args["env_kwargs"]]
    variant_steps = [int(v["max_steps"]) for v in pool if isinstance(v, dict) and v.get("max_steps")]
    kwargs = dict(
        control_mode=control_mode or args["control_mode"] or family.control_mode,
        reward_mode=reward_mode,
        max_episode_steps=max_episode_steps or max([family.max_episode_steps, *variant_steps]),
        env_kwargs=args["env_kwargs"],
    )
    if family.task_observation_key:
        kwargs["task_observation_key"] = family.task_observation_key
    gpu = sim_backend in ("physx_cuda", "cuda", "gpu") or (
        sim_backend == "auto" and num_envs > 1 and torch.cuda.is_available()
    )
    if family.backend == "gymnasium":  # e.g. MuJoCo HalfCheetah (Appendix G): TorchRL's GymWrapper
        from drs_torchrl.envs.gym_family import make_gym_family_base

        base = make_gym_family_base(
            family,
            kwargs.pop("env_kwargs"),
            num_envs=num_envs,
            cpu_batching=cpu_batching,
            sim_backend=sim_backend,
            **kwargs,
        )
    elif num_envs > 1 and not gpu:
        # several CPU simulators: one ManiSkill env per TorchRL sub-env
        if cpu_batching == "parallel":
            make_one = functools.partial(_worker_env, env_id, family.all_info_keys, sim_backend="physx_cpu", **kwargs)
            base = ParallelEnv(num_envs, make_one)
        else:
            make_one = functools.partial(ManiSkillEnv, env_id, family.all_info_keys, sim_backend="physx_cpu", **kwargs)
            base = SerialEnv(num_envs, make_one)
    else:
        base = ManiSkillEnv(
            env_id, family.all_info_keys, num_envs=num_envs, sim_backend=sim_backend, render_mode=render_mode, **kwargs
        )
    env = TransformedEnv(base, StageIndicator(family.stage_keys))
    if semi_sparse_reward:
        env.append_transform(
            SemiSparseReward(
                family.num_stages, -family.num_stages if semi_sparse_offset is None else semi_sparse_offset
            )
        )
    if reward_offset:
        env.append_transform(RewardScaling(loc=float(reward_offset), scale=1.0))
    for t in transforms:
        env.append_transform(t)
    if seed is not None:
        env.set_seed(seed)
    return env


def _worker_env(*args, **kwargs) -> ManiSkillEnv:
    """A ManiSkill env in a ParallelEnv worker: Ctrl-C goes to the whole process group, and the
    trainer (not the worker) decides how to stop, so the worker ignores SIGINT."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    return ManiSkillEnv(*args, **kwargs)
