"""Demonstrations from a trained policy (``drs-demos --from-policy RUN``), as the paper's.

Appendix A: "The demonstrations are from a trained RL agent". This works for any family, including
those without a motion-planning solver (``turn_valve``, ``half_cheetah``, the asset-backed ones).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import torch
from tensordict import TensorDict

from drs_torchrl.demos.store import cut_at_success, demo_meta
from drs_torchrl.runtime.rundir import load_run_config
from drs_torchrl.tasks import get_family, with_stages, with_task_observation
from drs_torchrl.transforms.stages import StageIndicator


def record_policy_demos(
    policy_path: str | Path,
    variant: str | None = None,
    num: int = 100,
    *,
    seed: int = 0,
    variant_overrides: dict | None = None,
    deterministic: bool = True,
    max_episodes: int | None = None,
    progress: bool = True,
    task_observation: bool = False,
) -> tuple[TensorDict, dict]:
    """Roll out a trained ``drs-learn``/``drs-reuse`` policy until ``num`` episodes succeed; returns (states, meta).

    The env is the family's (``make_family_env``) with the run's controller, episode length and
    variant overrides (from the run's ``config.yaml`` when there is one; ``variant_overrides`` are
    applied on top). ``deterministic=False`` samples actions from the policy, which succeeds more
    often than its mean action early in training. Stops with ``RuntimeError`` after
    ``max_episodes`` (default ``20 * num``) episodes.
    """
    from omegaconf import OmegaConf
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from drs_torchrl.envs.factory import make_family_env
    from drs_torchrl.models import load_policy, read_policy_checkpoint

    file, ck = read_policy_checkpoint(policy_path)
    family = get_family(ck["family"])
    # the run's env settings, when the checkpoint sits in a run directory (RUN/checkpoints/policy.pt) of its family
    cfg_file = file.parent.parent / "config.yaml"
    env_cfg = {}
    if file.parent.name == "checkpoints" and cfg_file.is_file():
        env_cfg = OmegaConf.to_container(load_run_config(cfg_file.parent, needs=("env",))).get("env") or {}
        if env_cfg.get("family", family.name) != family.name:
            env_cfg = {}
    family = with_stages(family, env_cfg.get("stages"))  # a stage-ablation run observes only its stages
    family = with_task_observation(family, env_cfg.get("task_observation") or task_observation)
    overrides = {**(env_cfg.get("variant_overrides") or {}), **(variant_overrides or {})}
    variant = variant or env_cfg.get("split") or "train"  # default: the split the policy was trained on
    env = make_family_env(
        family,
        variant,
        variant_overrides=overrides or None,
        seed=seed,
        control_mode=env_cfg.get("control_mode"),
        max_episode_steps=env_cfg.get("max_episode_steps"),
    )
    try:
        actor, pmeta = load_policy(file, env.observation_spec, env.action_spec, family=family.name)
        keys = [
            k
            for k in ("observation", *family.all_info_keys, family.task_observation_key)
            if k and k in env.observation_spec.keys(True)
        ]
        labeller = StageIndicator(family.stage_keys)
        reward_keys = [
            k
            for k in ("observation", "stage_indicators", family.task_observation_key, *family.reward_in_keys)
            if k and k in env.observation_spec.keys(True)
        ]
        reward_keys = list(dict.fromkeys(reward_keys))
        limit = int(getattr(env.base_env, "max_episode_steps", 0) or 0)  # the env's time limit, or -1/0: unknown
        if limit <= 0:
            limit = int(env_cfg.get("max_episode_steps") or family.max_episode_steps)
        episodes, lengths, tried_ids = [], [], []
        max_episodes = int(max_episodes or 20 * num)
        tried, t0 = 0, time.time()
        mode = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
        with set_exploration_type(mode), torch.no_grad():
            while len(episodes) < num:
                if tried >= max_episodes:
                    raise RuntimeError(
                        f"the policy succeeded in only {len(episodes)} of {tried} episodes on "
                        f"{family.name}/{variant}" + ("; try --stochastic" if deterministic else "")
                    )
                td = env.rollout(limit, actor, break_when_any_done=True)
                tried += 1
                nxt = td["next"]
                states = TensorDict({k: nxt[k].clone() for k in keys}, batch_size=[td.shape[0]])
                # what (s, a) rewards such as GAIL's need: the action taken and the state it was taken in
                states.set("action", td["action"].clone().float())
                states.set(
                    "state",
                    TensorDict(
                        {k: td[k].clone() for k in (*reward_keys, "stage") if k in td.keys()}, batch_size=[td.shape[0]]
                    ),
                )
                states = cut_at_success(states, labeller, len(episodes))
                if progress:
                    print(
                        f"\r  {len(episodes) + (states is not None)}/{num} demos from {tried} episodes "
                        f"({time.time() - t0:.0f}s)",
                        end="",
                        file=sys.stderr,
                        flush=True,
                    )
                if states is None:
                    continue
                episodes.append(states)
                lengths.append(states.shape[0])
                tried_ids.append(tried - 1)
        if progress:
            print(file=sys.stderr)
    finally:
        env.close()
    args = family.env_args(variant, overrides or None)
    data = torch.cat(episodes, 0)
    meta = demo_meta(
        family,
        data,
        env_id=args.get("env_id", family.env_id),
        variant=variant,
        variant_kwargs=args.get("env_kwargs", {}),
        lengths=lengths,
        seeds=[seed] * len(episodes),
        solver=f"policy:{file} (frames {pmeta.get('frames')}, {'deterministic' if deterministic else 'stochastic'})",
        episode_indices=tried_ids,
        max_episode_steps=limit,
        episodes_tried=tried,
        success_rate=len(episodes) / tried,
        # actions are the agent's own (its controller), with the states they were taken in ("state")
        actions={
            "control_mode": env_cfg.get("control_mode") or args.get("control_mode") or family.control_mode,
            "size": int(data["action"].shape[-1]),
        },
    )
    return data, meta
