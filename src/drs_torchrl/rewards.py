"""The reward slot of the training loop: DrS (learned or reused) and the paper's baselines.

Every reward is a choice of (a) ManiSkill's reward mode for the raw env reward, (b) whether the stage
transform writes the semi-sparse reward, (c) a transform in the env (static rewards, computed once
per step) and/or (d) a transform on replay-buffer samples (rewards that change while training, so
they are recomputed from the current modules when SAC samples; Sec. 4, Algorithm 1 line 18).

**The registry is ``conf/reward/``** (read by :mod:`drs_torchrl.apps.reward_registry`, not here): a reward exists
when ``conf/reward/<name>.yaml`` does, and that file names what builds it by ``_target_``: ``slot`` (one of the
functions below: what the run's reward slot holds in either phase) and, for a learned reward, ``model`` (its
networks, e.g. ``DrSReward.from_env``), ``learner`` (its phase-1 :mod:`drs_torchrl.learners` class, with its
settings) and ``reuses`` (the method of the ``reward.pt`` its phase 2 loads, when it is not its own name). No module
lists reward names. Adding a learned reward: a learner class and one YAML (docs/rewards.md).

Learned rewards: ``drs``, and the baselines ``vice_raq``, ``oril``, ``gail`` and ``gail_stages`` (GAIL's
reward plus the semi-sparse one in reuse, Appendix F.2). Static baselines of Sec. 5.2: ``sparse`` (success),
``semi_sparse`` (Eq. 2), ``dense`` (ManiSkill's human-engineered normalized dense reward, shifted by -1 so that its
maximum is 0 and ending an episode on success beats hovering short of it, as for every other reward here; for a
Gymnasium family such as HalfCheetah, Appendix G, the env's own reward, unshifted).
"""

from __future__ import annotations

from dataclasses import dataclass

from hydra.utils import get_object, instantiate
from omegaconf import DictConfig, OmegaConf
from torchrl.envs.transforms import Transform

from drs_torchrl.tasks import TaskFamily
from drs_torchrl.transforms.classifier_reward import ClassifierReward
from drs_torchrl.transforms.reward import DrSReward, RewardCheckpointError, load_reward


def reward_entry(cfg) -> DictConfig:
    """What builds the reward ``cfg`` (a ``reward`` config node as composed from ``conf/reward/<name>.yaml``): the
    node itself, which names its ``slot`` (and ``model``, ``learner``, ``reuses``)."""
    if cfg.get("slot") is None:
        raise ValueError(
            f"the reward config {cfg.get('name')!r} names no builder (slot): compose it from conf/reward/ "
            "(drs_torchrl.apps.reward_registry.with_builders fills in a saved or partial one)"
        )
    return cfg


def is_learned(cfg) -> bool:
    """A reward that phase 1 learns (its entry names a ``learner``)."""
    return reward_entry(cfg).get("learner") is not None


def reused_method(cfg) -> str:
    """The learner whose checkpoint a learned reward reuses (``reuses``, else its own name)."""
    return str(reward_entry(cfg).get("reuses") or cfg.name)


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
    """The reward slot of a run from the ``reward`` config group (``cfg.reward``): its entry's ``slot`` builder."""
    return instantiate(reward_entry(cfg).slot)(cfg, phase)


def env_reward(cfg, phase: str, mode: str = "sparse") -> RewardSetup:
    """``sparse`` / ``dense``: the env's own reward in ManiSkill's reward ``mode``, shifted by ``cfg.offset``
    (dense; None: the family's default, :func:`dense_offset`)."""
    _reads_no_checkpoint(cfg)
    off = cfg.get("offset")
    return RewardSetup(cfg.name, env_reward_mode=mode, env_reward_offset=None if off is None else float(off))


def semi_sparse_reward(cfg, phase: str) -> RewardSetup:
    """``semi_sparse`` (Eq. 2): the stage index written by the stage transform, shifted by ``cfg.offset`` (None: -N)."""
    _reads_no_checkpoint(cfg)
    off = cfg.get("offset")
    return RewardSetup(cfg.name, semi_sparse=True, semi_sparse_offset=None if off is None else float(off))


def static_checkpoint_error(name: str, checkpoint, key: str = "reward") -> str:
    """The refusal for a static reward given a checkpoint: the run would ignore it (a user who meant to reuse a
    learned reward would get the baseline). ``key`` is how the app names the reward (``reward`` or ``reward.name``)."""
    return (
        f"{key}={name} is a static reward and reads no checkpoint, so reward.checkpoint={checkpoint} would be "
        f"ignored: drop it, or reuse the learned reward with the reward that learned it (e.g. {key}=drs)"
    )


def _reads_no_checkpoint(cfg) -> None:
    """Refuse a ``reward.checkpoint`` given to a static reward (:func:`static_checkpoint_error`)."""
    if cfg.get("checkpoint"):
        raise ValueError(static_checkpoint_error(cfg.name, cfg.checkpoint))


def learned_reward(cfg, phase: str) -> RewardSetup:
    """A learned reward: phase 1 learns it (the run builds its ``learner``), phase 2 loads ``cfg.checkpoint``
    frozen, checked to come from the learner it reuses."""
    name, method = cfg.name, reused_method(cfg)
    if phase == "learn":
        if cfg.get("checkpoint"):
            raise ValueError(f"reward.checkpoint is for drs-reuse; drs-learn learns the {name} reward from scratch")
        return RewardSetup(name)
    if not cfg.get("checkpoint"):
        raise ValueError(
            f"drs-reuse with reward={name} needs reward.checkpoint=PATH (a reward.pt written by drs-learn reward={method})"
        )
    frozen = load_reward(cfg.checkpoint)
    got = "drs" if isinstance(frozen, DrSReward) else frozen.method
    if got != method:
        raise RewardCheckpointError(
            f"reward={name} reuses a reward learned by drs-learn reward={method}, "
            f"but {cfg.checkpoint} was learned by reward={got}; use reward={got}"
        )
    return RewardSetup(name, frozen=_frozen(frozen))


# reward.* settings a reused DrS reward brings from its checkpoint (Eq. 4's form, its inputs and networks), whatever
# the config says: the frozen reward is reused as it was learned
FROZEN_SETTINGS = ("formula", "alpha", "offset", "hidden", "activation", "in_keys")


def frozen_settings(reward) -> dict:
    """The :data:`FROZEN_SETTINGS` a frozen reward was learned with (a classifier reward: none)."""
    desc = reward.description() if isinstance(reward, DrSReward) else {}
    return {k: desc[k] for k in FROZEN_SETTINGS if k in desc}


def differs(setting, value) -> bool:
    """A config value that is not the checkpoint's (numbers to 1e-6, key lists and sizes as lists; null is unset)."""
    if setting is None:
        return False
    setting = OmegaConf.to_container(setting) if OmegaConf.is_config(setting) else setting
    if isinstance(value, float) and isinstance(setting, (int, float)) and not isinstance(setting, bool):
        return abs(float(setting) - value) > 1e-6 * max(1.0, abs(value))
    if isinstance(value, list) and isinstance(setting, (list, tuple)):
        return [str(v) for v in setting] != [str(v) for v in value]
    return setting != value


def reused_reward_settings(cfg, frozen) -> tuple[dict, list[str]]:
    """The settings a reused DrS reward was learned with (a reused reward is used as it was learned; the run records
    them in its ``config.yaml``), and one note per setting the ``reward`` config ``cfg`` gave otherwise."""
    settings = frozen_settings(frozen)
    notes = [
        f"reward.{key}={cfg.get(key)} is not used: the reused reward was learned with {key}={value}"
        for key, value in settings.items()
        if differs(cfg.get(key), value)
    ]
    return settings, notes


def gail_stages_reward(cfg, phase: str) -> RewardSetup:
    """Appendix F.2, GAIL with stage indicators: phase 1 learns GAIL; phase 2 combines a GAIL checkpoint linearly
    with the semi-sparse reward, ``classifier_weight * log D + stage_weight * (k - N)``."""
    setup = learned_reward(cfg, phase)
    if setup.frozen is not None:
        setup.frozen = _frozen(
            ClassifierReward.from_checkpoint(
                cfg.checkpoint, stage_weight=float(cfg.stage_weight), classifier_weight=float(cfg.classifier_weight)
            )
        )
    return setup


def _frozen(reward: Transform) -> Transform:
    reward.requires_grad_(False)
    reward.eval()
    return reward


def dense_offset(setup: RewardSetup, family: TaskFamily) -> float:
    """The shift of the env's own reward: ``reward.offset``, else -1 for ManiSkill's normalized dense
    reward (at most 1, episodes end on success: without it an agent that hovers just short of success
    out-earns one that succeeds, at gamma 0.8 ~4 against 1) and 0 otherwise."""
    if setup.env_reward_offset is not None:
        return setup.env_reward_offset
    return -1.0 if setup.name == "dense" and family.backend == "maniskill" else 0.0


def stage_buffers_hold_demos(cfg) -> bool:
    """Whether a reward's learner files the demonstrations into stage buffers that its training state saves
    (``RewardLearner.stage_buffers_hold_demos``: DrS); False for a static reward or a learner that does not say."""
    node = reward_entry(cfg).get("learner")
    return node is not None and bool(getattr(get_object(node._target_), "stage_buffers_hold_demos", False))


def new_reward_learner(
    cfg,
    family: TaskFamily,
    env,
    metadata: dict,
    *,
    device,
    autocast,
    step_fn,
    demos=None,
    reward_updates_per_update: float = 1.0,
):
    """The phase-1 learner of ``reward=<name>`` (``cfg`` is the ``reward`` config group), built from its entry alone:
    ``model`` (the reward's networks, sized from ``env``: ``DrSReward.from_env``, ``ClassifierReward.from_env``) and
    ``learner`` (the :mod:`drs_torchrl.learners` class that trains it), each a partial whose settings link to the
    node's (``${..disc.lr}``, ...). The run adds what it owns: ``device``, ``autocast``, ``step_fn(loss,
    optimizers)``, the ``demos`` (every learner takes them) and ``reward_updates_per_update``, the algorithm's
    ``algo.reward_updates_per_update``."""
    entry = reward_entry(cfg)
    in_keys = list(cfg.get("in_keys") or family.reward_in_keys)
    model = instantiate(entry.model)(env, family.num_stages, in_keys, metadata=metadata).to(device)
    return instantiate(entry.learner)(
        model,
        demos=demos,
        device=device,
        autocast=autocast,
        step_fn=step_fn,
        reward_updates_per_update=float(reward_updates_per_update),
    )
