"""Task families: the one place that knows a family's envs, variants, stage indicators and split.

A task family (Sec. 3) is a set of task variants that share a success criterion and differ in
objects, initial states or dynamics. Everything downstream (env construction, the stage transform,
the reward's inputs, the train/test split) reads a :class:`TaskFamily` instead of special-casing
tasks. ``get_family(name)`` looks one up; ``register_family`` adds one. Each family lives in its own
module of this package (``tasks/pick_cube.py``...), imported at the bottom of this file.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import inspect

from dataclasses import dataclass, field
from typing import Any

from drs_torchrl.runtime.errors import ConfigError, UserError


@dataclass(frozen=True)
class TaskFamily:
    """Description of a task family.

    Attributes:
        name: registry key (``env=<name>`` on the command line).
        env_id: ManiSkill environment id that the variants parameterise (a variant may name its own
            ``env_id``; the variants of one split must then agree on it).
        stage_keys: ordered stage indicators (Appendix A); the last one is ``"success"``. Stage ``k`` of a
            state is the number of (monotone) indicators that hold, so ``N = len(stage_keys)``.
        info_keys: info entries copied into the TensorDict (at least ``stage_keys``).
        reward_in_keys: observation entries the learned reward reads.
        variants: named variants, each a dict of environment keyword arguments (a ``control_mode``
            entry overrides the family's for that variant).
        train_variants / test_variants: disjoint variant names for reward learning / reuse.
        control_mode, max_episode_steps: as in the paper's setup (EE delta position control).
        backend: simulator that builds ``env_id``: ``"maniskill"`` (ManiSkill3/SAPIEN) or
            ``"gymnasium"`` (a Gymnasium env through TorchRL's ``GymWrapper``, e.g. the MuJoCo
            locomotion family of Appendix G; see ``drs_torchrl.envs.gym_family``).
        pooled: the env takes all variants of a split (``variants=[...]``, ``variant_names=[...]``)
            and draws one per episode (``drs_torchrl.envs.variants.pool``). Otherwise
            ``env.split=train|test`` means the split's first variant.
        task_observation_key: if set, the env also writes its robot-agnostic task state under
            this key (name it in ``reward_in_keys`` for rewards that transfer between robots).
    """

    name: str
    env_id: str
    stage_keys: tuple[str, ...]
    variants: dict[str, dict[str, Any]]
    train_variants: tuple[str, ...]
    test_variants: tuple[str, ...]
    info_keys: tuple[str, ...] = ()
    reward_in_keys: tuple[str, ...] = ("observation", "stage_indicators")
    control_mode: str | None = "pd_ee_delta_pos"
    max_episode_steps: int = 50
    description: str = ""
    extra: dict[str, Any] = field(default_factory=dict)
    backend: str = "maniskill"
    pooled: bool = False
    task_observation_key: str | None = None

    def __post_init__(self):
        if self.backend not in ("maniskill", "gymnasium"):
            raise ValueError(f"family {self.name!r}: backend must be 'maniskill' or 'gymnasium', got {self.backend!r}")
        if not self.stage_keys:
            raise ValueError(f"family {self.name!r}: stage_keys must name at least the success indicator")
        if self.stage_keys[-1] != "success":  # episodes, demonstrations and evaluation read info["success"]
            raise ValueError(
                f"family {self.name!r}: the last stage indicator must be the env's success flag 'success' "
                f"(info['success']), got stage_keys={list(self.stage_keys)}"
            )
        overlap = set(self.train_variants) & set(self.test_variants)
        if overlap:
            raise ValueError(f"family {self.name!r}: train and test variants overlap: {sorted(overlap)}")
        unknown = (set(self.train_variants) | set(self.test_variants)) - set(self.variants)
        if unknown:
            raise ValueError(f"family {self.name!r}: split names unknown variants {sorted(unknown)}")

    @property
    def num_stages(self) -> int:
        return len(self.stage_keys)

    @property
    def all_info_keys(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys((*self.info_keys, *self.stage_keys)))

    def split_variants(self, split: str) -> tuple[str, ...]:
        """Variant names of ``split``: ``"train"``, ``"test"`` or one variant's name."""
        if split == "train":
            return self.train_variants
        if split == "test":
            if not self.test_variants:
                raise KeyError(
                    f"family {self.name!r} has no test variants; name some (env.test_variants=[...] for a "
                    "family defined in config) or pick a variant with env.split=<variant>"
                )
            return self.test_variants
        if split not in self.variants:
            self.variant_kwargs(split)  # raises the KeyError naming the known variants
        return (split,)

    def env_args(self, split: str, overrides: dict | None = None) -> dict[str, Any]:
        """What builds the env of ``split``: ``env_id``, ``env_kwargs`` and ``control_mode`` (None: the family's).

        A pooled family gets every variant of the split (``env_kwargs = {"variants": [...],
        "variant_names": [...]}``, ``overrides`` applied to each), drawn per episode by the env;
        any other family the split's first variant's kwargs, as :meth:`variant_kwargs`.
        """
        names = self.split_variants(split) if self.pooled else (split,)
        kwargs = [self.variant_kwargs(n, overrides) for n in names]
        special = {}
        for key, default in (("env_id", self.env_id), ("control_mode", None)):
            values = [kw.pop(key, default) for kw in kwargs]
            if any(v != values[0] for v in values):
                raise ValueError(
                    f"family {self.name!r}: the variants of split {split!r} differ in {key} ({values}); "
                    "one env cannot draw among them per episode"
                )
            special[key] = values[0]
        if self.pooled:
            env_kwargs = {"variants": kwargs, "variant_names": list(names)}
        else:
            env_kwargs = kwargs[0]
        return {"env_id": special["env_id"], "env_kwargs": env_kwargs, "control_mode": special["control_mode"]}

    def variant_kwargs(self, variant: str, overrides: dict | None = None) -> dict[str, Any]:
        """Environment kwargs of ``variant`` (``"train"``/``"test"`` mean the split's first variant)."""
        if variant == "train":
            variant = self.train_variants[0]
        elif variant == "test":
            variant = self.test_variants[0]
        if variant not in self.variants:
            raise KeyError(
                f"family {self.name!r} has no variant {variant!r}; known: {sorted(self.variants)} "
                f"(or 'train'/'test'). Set a parameter directly with env.variant_overrides."
            )
        kwargs = {**self.variants[variant], **(overrides or {})}
        if overrides:
            self.check_overrides(overrides, kwargs.get("env_id", self.env_id))
        return kwargs

    def check_overrides(self, overrides: dict, env_id: str | None = None) -> None:
        """Raise :class:`~drs_torchrl.runtime.errors.ConfigError` naming each key of ``overrides`` (``env.variant_overrides``,
        ``--override``) that is neither a variant parameter of the family nor a keyword argument of its env
        (``env_id``, default the family's), with the close match of a typo; an env whose arguments cannot be
        read (not installed, not registered, ``**kwargs``) is left to its constructor."""
        params = _env_parameters(self.backend, env_id or self.env_id)
        if params is None:
            return
        special = {"env_id", "control_mode"}  # a variant may name its own (env_args)
        per_variant = (set(params[0]) | {k for v in self.variants.values() for k in v}) - special
        others = (set(params[1]) | special) - per_variant
        unknown = [k for k in overrides if k not in per_variant | others]
        if not unknown:
            return
        named = []
        for key in unknown:
            close = difflib.get_close_matches(str(key), sorted(per_variant | others), n=1)
            named.append(f"{key!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
        raise ConfigError(
            f"family {self.name!r} has no variant parameter {', '.join(named)}; its variant parameters: "
            f"{sorted(per_variant)}, and {env_id or self.env_id} also takes {sorted(others)}"
        )


# keyword arguments that ManiSkillEnv / the pooled envs set themselves (envs/maniskill.py, envs/variants/pool.py)
_SET_BY_DRS = frozenset(
    {"variants", "variant_names", "num_envs", "obs_mode", "sim_backend", "reward_mode", "render_mode"}
)


@functools.lru_cache(maxsize=None)
def _env_parameters(backend: str, env_id: str) -> tuple[tuple[str, ...], tuple[str, ...]] | None:
    """(per-variant parameters, other keyword arguments) of the env ``env_id`` builds; None where they cannot be
    read: the env is not installed or registered, or its constructor takes any ``**kwargs``. Imports the
    simulator (once): call it when an env is about to be built."""
    try:
        if backend == "gymnasium":
            import gymnasium

            from drs_torchrl.envs.gym_family import WRAPPER_KWARGS

            entry = gymnasium.spec(env_id).entry_point
            creator = gymnasium.envs.registration.load_env_creator(entry) if isinstance(entry, str) else entry
            per_variant, reserved = tuple(WRAPPER_KWARGS), frozenset()
        else:
            import mani_skill.envs  # noqa: F401  (registers ManiSkill's envs)
            from mani_skill.utils.registration import REGISTERED_ENVS

            import drs_torchrl.envs.variants  # noqa: F401  (registers drs-torchrl's)

            creator = REGISTERED_ENVS[env_id].cls
            per_variant, reserved = tuple(getattr(creator, "VARIANT_DEFAULTS", {})), _SET_BY_DRS
    except Exception:  # not installed, not registered: building the env says so
        return None
    keywords = _constructor_keywords(creator)
    if keywords is None:
        return None
    return per_variant, tuple(sorted(keywords - reserved - set(per_variant)))


def _constructor_keywords(creator) -> set[str] | None:
    """The keyword arguments an env class (following ``**kwargs`` up its base classes) or function takes; None if
    it passes ``**kwargs`` on to a constructor that takes anything."""
    if isinstance(creator, type):
        inits = [k.__dict__["__init__"] for k in creator.__mro__ if "__init__" in k.__dict__]
    else:
        inits = [creator]
    names: set[str] = set()
    for init in inits:
        try:
            params = list(inspect.signature(init).parameters.values())
        except (TypeError, ValueError):
            return None
        names |= {p.name for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
        if not any(p.kind is p.VAR_KEYWORD for p in params):
            return names - {"self"}
    return None


def column_groups(*sizes: tuple[str, int]) -> dict[str, tuple[int, int]]:
    """Named column ranges of a flat observation from the sizes of its parts, in order (``drs-probe --swap-with``)."""
    groups, start = {}, 0
    for name, size in sizes:
        groups[name] = (start, start + size)
        start += size
    return groups


# a ManiSkill state observation with the Panda starts with its qpos (7 arm + 2 finger joints) and qvel (9)
PANDA_STATE = (("arm joint positions", 7), ("finger joint positions", 2), ("joint velocities", 9))

_FAMILIES: dict[str, TaskFamily] = {}


def register_family(family: TaskFamily) -> TaskFamily:
    _FAMILIES[family.name] = family
    return family


class UnknownFamilyError(UserError, KeyError):
    """A task family name that no built-in or config-defined family has."""

    def __str__(self) -> str:  # the message, not KeyError's repr of it
        return str(self.args[0])


def get_family(name: str) -> TaskFamily:
    try:
        return _FAMILIES[name]
    except KeyError:
        raise UnknownFamilyError(f"unknown task family {name!r}; known families: {sorted(_FAMILIES)}") from None


def list_families(include_config: bool = False) -> list[str]:
    """Names of the built-in families (and, with ``include_config``, of those defined in config this process)."""
    return sorted(n for n, f in _FAMILIES.items() if include_config or not f.extra.get("from_config"))


# env-config fields of a family defined entirely in config (conf/env/custom.yaml)
CONFIG_FAMILY_FIELDS = (
    "env_id",
    "stage_keys",
    "info_keys",
    "reward_in_keys",
    "variants",
    "train_variants",
    "test_variants",
)


def _names(value, key: str) -> tuple[str, ...]:
    """A list setting's entries as names; one value where a list belongs is refused (a string would be read letter
    by letter: ``env.stage_keys=success`` as ``s, u, c, ...``)."""
    if value is None:
        return ()
    if isinstance(value, (str, bytes, int, float, bool)) or hasattr(value, "items") or not hasattr(value, "__iter__"):
        raise ValueError(f"{key} must be a list, e.g. {key}=[{value}], got {value!r}")
    return tuple(str(v) for v in value)


def family_from_config(env_cfg, task_observation: bool | None = None) -> TaskFamily:
    """The task family of an ``env`` config: a registered one (``env=pick_cube``), or one the config
    defines itself (``env=custom env.family=NAME env.env_id=... env.stage_keys=[...]``), which is
    registered under its name so that checkpoints and reuse find it. ``task_observation``: not None, instead of
    ``env.task_observation`` (a run whose reward reads the task state turns it on)."""
    if task_observation is None:
        task_observation = env_cfg.get("task_observation")
    if env_cfg.get("env_id") is None:
        return with_task_observation(with_stages(get_family(env_cfg.family), env_cfg.get("stages")), task_observation)
    name = str(env_cfg.family)
    if name in _FAMILIES and not _FAMILIES[name].extra.get("from_config"):
        raise ValueError(
            f"env.family={name!r} is a built-in family; give the family defined in config another name "
            f"(e.g. env.family=my_{name})"
        )

    def _list(key):
        return _names(env_cfg.get(key), f"env.{key}")

    raw = env_cfg.get("variants") or {"default": {}}
    example = "e.g. env.variants={small: {cube_half_size: 0.015}}"
    if not hasattr(raw, "items"):
        raise ValueError(f"env.variants must map each variant's name to its parameters ({example}), got {raw!r}")
    for k, v in raw.items():
        if v is not None and not hasattr(v, "items"):
            raise ValueError(f"env.variants.{k} must be a mapping of the env's parameters ({example}), got {v!r}")
    variants = {str(k): dict(v or {}) for k, v in raw.items()}
    train = _list("train_variants") or (next(iter(variants)),)
    try:
        family = TaskFamily(
            name=name,
            env_id=str(env_cfg.env_id),
            stage_keys=_list("stage_keys"),
            info_keys=_list("info_keys"),
            reward_in_keys=_list("reward_in_keys") or ("observation", "stage_indicators"),
            variants=variants,
            train_variants=train,
            test_variants=_list("test_variants"),
            control_mode=env_cfg.get("control_mode") or "pd_ee_delta_pos",
            max_episode_steps=int(env_cfg.get("max_episode_steps") or 50),
            description=f"defined in config: {env_cfg.env_id} with stages {list(_list('stage_keys'))}",
            extra={"from_config": True},
        )
    except ValueError as exc:
        raise ValueError(
            f"env=custom: {exc} (set env.stage_keys, env.variants, env.train_variants, env.test_variants)"
        ) from None
    return with_task_observation(with_stages(register_family(family), env_cfg.get("stages")), task_observation)


def with_stages(family: TaskFamily, stages) -> TaskFamily:
    """``family`` with only ``stages`` of its stage indicators (``None``: all of them): the paper's stage
    ablations (Sec. 5.4.1; e.g. ``env.stages=[success]``, "w/o stage indicators"). The dropped
    indicators stay info keys; the stage index, ``stage_indicators`` and ``N`` follow the subset."""
    if not stages:
        return family
    stages = _names(stages, "env.stages")
    unknown = [k for k in stages if k not in family.stage_keys]
    if unknown:
        raise ValueError(
            f"env.stages names {unknown}, which are not stage indicators of family {family.name!r} "
            f"(its stages: {list(family.stage_keys)})"
        )
    if stages[-1] != family.stage_keys[-1]:
        raise ValueError(
            f"env.stages must end with the success indicator {family.stage_keys[-1]!r}, got {list(stages)}"
        )
    if list(stages) != [k for k in family.stage_keys if k in stages] or len(set(stages)) != len(stages):
        raise ValueError(
            f"env.stages must keep the family's order without repeats ({list(family.stage_keys)}), got {list(stages)}"
        )
    if stages == family.stage_keys:
        return family
    return dataclasses.replace(
        family,
        stage_keys=stages,
        info_keys=family.all_info_keys,
        extra={**family.extra, "stage_subset_of": list(family.stage_keys)},
    )


TASK_OBSERVATION_KEY = "task_observation"


def with_task_observation(family: TaskFamily, on) -> TaskFamily:
    """``family`` whose env also writes its robot-agnostic task state under ``task_observation``
    (``env.task_observation=true``; the pick families' envs have one: object pose, goal, TCP position and
    the vectors between them, no joint positions or velocities). A reward learned with
    ``reward.in_keys=[task_observation,stage_indicators]`` cannot key on the robot's joints, e.g. on the
    joint velocities that a success which needs a static robot makes tell-tale (results/reuse/pick_cube/)."""
    if not on or family.task_observation_key:
        return family
    if not family.extra.get("task_observation_groups"):  # the families whose env has a task_observation()
        have = [f.name for f in _FAMILIES.values() if f.extra.get("task_observation_groups") or f.task_observation_key]
        raise ValueError(
            f"env.task_observation=true (or a reward that reads {TASK_OBSERVATION_KEY!r}): family "
            f"{family.name!r} has no task state; the families that have one: {sorted(have)}"
        )
    return dataclasses.replace(family, task_observation_key=TASK_OBSERVATION_KEY)


# one module per family; each registers itself on import
from drs_torchrl.tasks import pick_cube  # noqa: E402,F401
from drs_torchrl.tasks import pick_and_place  # noqa: E402,F401
from drs_torchrl.tasks import turn_valve  # noqa: E402,F401
from drs_torchrl.tasks import stack_cube  # noqa: E402,F401
from drs_torchrl.tasks import place_sphere  # noqa: E402,F401
from drs_torchrl.tasks import cross_robot  # noqa: E402,F401
from drs_torchrl.tasks import pick_ycb  # noqa: E402,F401
from drs_torchrl.tasks import turn_faucet  # noqa: E402,F401
from drs_torchrl.tasks import open_cabinet_door  # noqa: E402,F401
from drs_torchrl.tasks import half_cheetah  # noqa: E402,F401
