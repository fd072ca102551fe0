"""The reward slot of the training loop: DrS (learned or reused) and the paper's baselines.

Every reward is a choice of (a) ManiSkill's reward mode for the raw env reward, (b) whether the stage
transform writes the semi-sparse reward, (c) a transform in the env (static rewards, computed once
per step) and/or (d) a transform on replay-buffer samples (rewards that change while training, so
they are recomputed from the current modules when SAC samples; Sec. 4, Algorithm 1 line 18).

Learned rewards (phase 1 learns them with a :mod:`drs_torchrl.learners` learner, phase 2 reuses the
checkpoint): ``drs``, and the baselines ``vice_raq``, ``oril``, ``gail`` and ``gail_stages`` (GAIL's
reward plus the semi-sparse one in reuse, Appendix F.2).

Static baselines of Sec. 5.2: ``sparse`` (success), ``semi_sparse`` (Eq. 2), ``dense`` (ManiSkill's
human-engineered normalized dense reward, shifted by -1 so that its maximum is 0 and ending an episode
on success beats hovering short of it, as for every other reward here; for a Gymnasium family such as
HalfCheetah, Appendix G, the env's own reward, unshifted).
"""

from __future__ import annotations

from dataclasses import dataclass

from torchrl.envs.transforms import Transform

from drs_torchrl.tasks import TaskFamily
from drs_torchrl.transforms.classifier_reward import ClassifierReward
from drs_torchrl.transforms.reward import DrSReward, RewardCheckpointError, load_reward

LEARNED = ("drs", "vice_raq", "oril", "gail", "gail_stages")
REWARDS = (*LEARNED, "sparse", "semi_sparse", "dense")
# the learner whose checkpoint each learned reward reuses
_CHECKPOINT_METHOD = {"drs": "drs", "vice_raq": "vice_raq", "oril": "oril", "gail": "gail", "gail_stages": "gail"}


@dataclass
class RewardSetup:
    name: str
    env_reward_mode: str = "sparse"
    semi_sparse: bool = False
    semi_sparse_offset: float | None = None  # None: -N
    env_reward_offset: float | None = None  # added to the env's own reward (dense; None: the family's default)
    learned: Transform | None = None  # trained in this run (phase 1), by a drs_torchrl.learners learner
    frozen: Transform | None = None  # applied inside the env (phase 2 / static)


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
        off = cfg.get("offset")
        return RewardSetup(
            name, env_reward_mode="normalized_dense", env_reward_offset=None if off is None else float(off)
        )
    # a learned reward: phase 1 learns it (Trainer builds the learner), phase 2 loads it frozen
    if phase == "learn":
        if cfg.get("checkpoint"):
            raise ValueError(f"reward.checkpoint is for drs-reuse; drs-learn learns the {name} reward from scratch")
        return RewardSetup(name)
    if not cfg.get("checkpoint"):
        raise ValueError(
            f"drs-reuse with reward={name} needs reward.checkpoint=PATH (a reward.pt written by "
            f"drs-learn reward={_CHECKPOINT_METHOD[name]})"
        )
    frozen = load_reward(cfg.checkpoint)
    method = "drs" if isinstance(frozen, DrSReward) else frozen.method
    if method != _CHECKPOINT_METHOD[name]:
        raise RewardCheckpointError(
            f"reward={name} reuses a reward learned by drs-learn reward={_CHECKPOINT_METHOD[name]}, "
            f"but {cfg.checkpoint} was learned by reward={method}; use reward={method}"
        )
    if name == "gail_stages":  # Appendix F.2: GAIL's reward combined linearly with the semi-sparse one
        frozen = ClassifierReward.from_checkpoint(
            cfg.checkpoint, stage_weight=float(cfg.stage_weight), classifier_weight=float(cfg.classifier_weight)
        )
    frozen.requires_grad_(False)
    frozen.eval()
    return RewardSetup(name, frozen=frozen)


def dense_offset(setup: RewardSetup, family: TaskFamily) -> float:
    """The shift of the env's own reward: ``reward.offset``, else -1 for ManiSkill's normalized dense
    reward (at most 1, episodes end on success: without it an agent that hovers just short of success
    out-earns one that succeeds, at gamma 0.8 ~4 against 1) and 0 otherwise."""
    if setup.env_reward_offset is not None:
        return setup.env_reward_offset
    return -1.0 if setup.name == "dense" and family.backend == "maniskill" else 0.0


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


def new_classifier_reward(cfg, family: TaskFamily, observation_spec, action_spec, metadata: dict) -> ClassifierReward:
    """A fresh classifier reward for a baseline's phase 1 (``vice_raq``, ``oril``, ``gail``)."""
    in_keys = list(cfg.get("in_keys") or family.reward_in_keys)
    shapes = {}
    for k in in_keys:
        if k not in observation_spec.keys(True, True):
            raise KeyError(
                f"reward input {k!r} is not in the observation spec; it has {list(observation_spec.keys(True, True))}"
            )
        shapes[k] = int(observation_spec[k].shape[-1])
    use_action = bool(cfg.get("use_action", False))
    return ClassifierReward(
        in_keys,
        shapes,
        family.num_stages,
        use_action=use_action,
        action_dim=int(action_spec.shape[-1]) if use_action else None,
        output=str(cfg.output),
        offset=float(cfg.get("offset") or 0.0),
        hidden=list(cfg.hidden),
        activation=str(cfg.activation),
        method=_CHECKPOINT_METHOD[cfg.name],
        metadata=metadata,
    )


def new_reward_learner(cfg, family: TaskFamily, env, metadata: dict, *, device, autocast, step_fn, demos=None):
    """The phase-1 learner of ``reward=<name>`` (``cfg`` is the ``reward`` config group)."""
    from drs_torchrl.learners import (
        DemoDiscriminatorLearner,
        DrSLearner,
        OfflineClassifierLearner,
        SuccessClassifierLearner,
    )

    d = cfg.disc
    common = dict(lr=float(d.lr), fused=bool(d.get("fused", False)), device=device, autocast=autocast, step_fn=step_fn)
    if cfg.name == "drs":
        reward = new_drs_reward(cfg, family, env.observation_spec, metadata).to(device)
        return DrSLearner(
            reward,
            capacity=int(cfg.stage_buffer_size),
            batch_size=int(d.batch_size),
            scratch_dir=cfg.get("stage_buffer_scratch_dir"),
            updates_per_rl_update=float(d.updates_per_sac_update),
            early_stop_threshold=d.early_stop_threshold,
            window=int(d.window),
            latch=bool(d.get("latch", True)),
            demos=demos,
            **common,
        )
    reward = new_classifier_reward(cfg, family, env.observation_spec, env.action_spec, metadata).to(device)
    common.update(batch_size=int(d.batch_size), updates_per_rl_update=float(d.updates_per_sac_update))
    if cfg.name == "vice_raq":
        return SuccessClassifierLearner(
            reward, success_key=family.stage_keys[-1], capacity=int(cfg.buffer_size), **common
        )
    if cfg.name == "oril":
        return OfflineClassifierLearner(
            reward,
            demos=demos,
            capacity=int(cfg.buffer_size),
            random_episodes=int(cfg.random_episodes),
            offline_updates=int(cfg.offline_updates),
            **common,
        )
    # gail, gail_stages (phase 1 of both is GAIL)
    return DemoDiscriminatorLearner(reward, demos=demos, grad_penalty=bool(cfg.get("grad_penalty", False)), **common)
