"""The ``make_*`` factories of a run, in the shape of TorchRL's ``sota-implementations``.

Each builds one TorchRL piece from the Hydra config and is usable on its own (from a notebook, or
another TorchRL script): the task family's envs with their reward in the slot, the replay buffer whose
sampling transform recomputes a learned reward, the reward-learning core, and the collector. The
algorithm itself (SAC's actor, critics, ``SACLoss``, optimisers; PPO's) is ``algo.updater``
(:mod:`drs_torchrl.updaters`).
:class:`~drs_torchrl.apps.build.Run` wires them into Algorithm 1.
"""

from __future__ import annotations

import functools
from typing import Any

import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from torchrl.envs.transforms import DeviceCastTransform

from drs_torchrl.envs.factory import make_family_env
from drs_torchrl.precision import autocast
from drs_torchrl.runtime.run_logger import RunLogger
from drs_torchrl.rewards import RewardSetup, dense_offset, new_reward_learner
from drs_torchrl.tasks import TaskFamily

__all__ = [
    "make_envs",
    "make_replay_buffer",
    "make_reward_learner",
    "make_collector",
    "make_logger",
]


def variant_overrides(node: DictConfig) -> dict | None:
    """The ``env`` node's ``variant_overrides`` as a plain dict (None when empty)."""
    return OmegaConf.to_container(node.variant_overrides) if node.get("variant_overrides") else None


def make_envs(
    node: DictConfig,
    family: TaskFamily,
    reward: RewardSetup,
    device: torch.device,
    *,
    seed: int,
    eval_split: str | None = None,
):
    """The training env (the ``env`` node's ``split``) and a one-env evaluation env (``eval_split``, else the same
    split), each with the family's stage labelling and the reward in its slot: the env's own reward (sparse,
    semi-sparse, dense), or a frozen learned reward appended as a transform (phase 2). Returns ``(env, eval_env,
    env_kwargs)``; ``env_kwargs`` rebuilds the same env elsewhere (a collector's worker process)."""
    env_kwargs = dict(
        variant_overrides=variant_overrides(node),
        reward_mode=reward.env_reward_mode,
        semi_sparse_reward=reward.semi_sparse,
        semi_sparse_offset=reward.semi_sparse_offset,
        reward_offset=dense_offset(reward, family),
        sim_backend=node.sim_backend,
        num_envs=node.num_envs,
        cpu_batching=node.get("cpu_batching", "serial"),
        control_mode=node.control_mode,
        max_episode_steps=node.max_episode_steps,
    )
    env = make_family_env(family, node.split, seed=int(seed), **env_kwargs)
    eval_env = make_family_env(
        family, eval_split or node.split, seed=int(seed) + 10_000, **{**env_kwargs, "num_envs": 1}
    )  # evaluation: one episode at a time
    for e in (env, eval_env):
        if e.device != device:  # e.g. CPU simulation feeding a CUDA learner: data moves at the env edge
            e.append_transform(DeviceCastTransform(device, orig_device=e.device))
    if reward.frozen is not None:
        reward.frozen.check_compatible(
            env.observation_spec,
            num_stages=family.num_stages,
            family=family.name,
            action_spec=env.action_spec,
            stage_keys=family.stage_keys,
        )
        reward.frozen.to(device)
        env.append_transform(reward.frozen)
        eval_env.append_transform(reward.frozen.clone())
    return env, eval_env, env_kwargs


def make_replay_buffer(node: DictConfig, transform, device: torch.device, batch_size: int | None = None):
    """The ``algo.replay_buffer`` node's buffer on ``device``; ``transform`` (a learned reward, or None) recomputes
    ``("next", "reward")`` from the current reward modules at every sample (Algorithm 1, line 18).
    ``batch_size`` replaces the node's (the agent's part of a batch that also holds demonstrations)."""
    extra = {} if batch_size is None else {"batch_size": int(batch_size)}
    return instantiate(node, storage={"device": str(device)}, **extra)(transform=transform)


def make_reward_learner(
    node: DictConfig,
    family: TaskFamily,
    env,
    *,
    split: str,
    variant_overrides: dict | None,
    seed: int,
    reward_updates_per_update: float,
    device: torch.device,
    precision: str,
    step_fn,
    demos: list | None = None,
):
    """The phase-1 reward learner of the ``reward`` node (:mod:`drs_torchrl.learners`), its checkpoint metadata
    describing the training ``split``, stepping ``reward_updates_per_update`` times per RL update (the algorithm's
    ``algo.reward_updates_per_update``). ``step_fn(loss, optimizers)``: backward and steps."""
    split_args = family.env_args(split, variant_overrides)
    meta: dict[str, Any] = {
        "family": family.name,
        "env_id": split_args["env_id"],
        "variant": split,
        "variant_kwargs": split_args["env_kwargs"],
        "stage_keys": list(family.stage_keys),
        "seed": int(seed),
    }
    return new_reward_learner(
        node,
        family,
        env,
        meta,
        device=device,
        autocast=functools.partial(autocast, precision, device),
        step_fn=step_fn,
        demos=demos,
        reward_updates_per_update=float(reward_updates_per_update or 1),
    )


def make_logger(node: DictConfig, run_dir, resume_step: int | None = None) -> RunLogger:
    """The ``logger`` node's :class:`~drs_torchrl.runtime.run_logger.RunLogger` in ``run_dir`` (CSV files,
    TensorBoard, optionally Weights & Biases); ``resume_step``: a resumed run's env steps so far."""
    return RunLogger(
        run_dir,
        tensorboard=node.tensorboard,
        csv_files=node.csv,
        resume_step=resume_step,
        wandb=bool(node.get("wandb", False)),
        wandb_project=node.get("wandb_project", "drs-torchrl"),
        wandb_mode=node.get("wandb_mode", "offline"),
    )


def make_collector(
    collector: DictConfig, env, policy, frames: int, *, learning_starts: int, frames_done: int, device: torch.device
):
    """The ``algo.collector`` node's TorchRL collector for the next ``frames`` env steps (``env`` may be a
    worker-process constructor), with random actions until ``learning_starts`` env steps in all."""
    return instantiate(collector)(
        env,
        policy,
        total_frames=frames,
        init_random_frames=max(0, int(learning_starts) - frames_done),
        device=device,
    )
