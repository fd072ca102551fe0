"""The reward slot of the training loop: DrS (learned or reused) and the paper's baselines.

Every reward is a choice of (a) ManiSkill's reward mode for the raw env reward, (b) whether the stage
transform writes the semi-sparse reward, (c) a transform in the env (static rewards, computed once
per step) and/or (d) a transform on replay-buffer samples (rewards that change while training, so
they are recomputed from the current modules when SAC samples; Sec. 4, Algorithm 1 line 18).

Baselines of Sec. 5.2: ``sparse`` (success), ``semi_sparse`` (Eq. 2), ``dense`` (ManiSkill's
human-engineered normalized dense reward; for a Gymnasium family such as HalfCheetah, Appendix G,
the env's own reward).
"""
from __future__ import annotations

from dataclasses import dataclass

from torchrl.envs.transforms import Transform

from drs_torchrl.tasks import TaskFamily
from drs_torchrl.transforms.reward import DrSReward

REWARDS = ("drs", "sparse", "semi_sparse", "dense")


@dataclass
class RewardSetup:
    name: str
    env_reward_mode: str = "sparse"
    semi_sparse: bool = False
    semi_sparse_offset: float | None = None  # None: -N
    learned: DrSReward | None = None  # trained in this run (phase 1)
    frozen: Transform | None = None  # applied inside the env (phase 2 / static)

    @property
    def replay_transform(self) -> Transform | None:
        return self.learned


def reward_setup(cfg, phase: str) -> RewardSetup:
    """Reward of a run from the ``reward`` config group (``cfg.reward``)."""
    name = cfg.name
    if name not in REWARDS:
        raise ValueError(f"unknown reward {name!r}; choose one of {REWARDS}")
    if name == "sparse":
        return RewardSetup(name, env_reward_mode="sparse")
    if name == "semi_sparse":
        off = cfg.get("offset")
        return RewardSetup(name, semi_sparse=True, semi_sparse_offset=None if off is None else float(off))
    if name == "dense":
        return RewardSetup(name, env_reward_mode="normalized_dense")
    # drs
    if phase == "learn":
        if cfg.get("checkpoint"):
            raise ValueError("reward.checkpoint is for drs-reuse; drs-learn learns the reward from scratch")
        return RewardSetup(name)
    if not cfg.get("checkpoint"):
        raise ValueError("drs-reuse with reward=drs needs reward.checkpoint=PATH (a reward.pt written by drs-learn)")
    frozen = DrSReward.from_checkpoint(cfg.checkpoint)
    frozen.requires_grad_(False)
    frozen.eval()
    return RewardSetup(name, frozen=frozen)


def new_drs_reward(cfg, family: TaskFamily, observation_spec, metadata: dict) -> DrSReward:
    """A fresh DrS reward for phase 1, its input sizes read from the env's spec."""
    return DrSReward.from_spec(
        observation_spec,
        family.num_stages,
        list(cfg.get("in_keys") or family.reward_in_keys),
        formula=cfg.formula,
        alpha=float(cfg.alpha),
        offset=float(cfg.get("offset", -2.0)),
        hidden=list(cfg.hidden),
        activation=cfg.activation,
        metadata=metadata,
    )
