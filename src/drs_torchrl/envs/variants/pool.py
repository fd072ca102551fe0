"""Per-episode variant sampling inside one ManiSkill scene.

A task family (DrS paper, Sec. 3 and Appendix A) is a set of variants that share a success
criterion and differ in objects, initial states or dynamics; reward learning trains on all the
training variants at once. A *pooled* env here receives the variants of a split
(``variants=[{...}, ...]`` with ``variant_names=[...]``) and draws one of them at every episode
reset from ManiSkill's seeded episode RNG, so runs stay reproducible from ``env.set_seed``.

Variants that change scene objects (size, shape, valve geometry) would need a ManiSkill
reconfiguration (rebuilding the scene) on every reset: about 0.3 s on the CPU backend, longer
than a 50-step episode. Instead, on the CPU backend (one env per process) every candidate object
of the pool is built once and the ones not in use are *parked* on the floor beside the table,
out of the robot's reach; a reset then costs a few pose writes (see ``results/families/README.md``
for the measured cost). On the GPU backend (``num_envs > 1``) each parallel env is given one
variant of the pool, round-robin, when the scene is built (objects of different shapes in
different sub-scenes, merged into one batched actor, as ManiSkill's own YCB tasks do), so every
variant is always being simulated; a ManiSkill reconfiguration re-deals them.

Parameters of a variant that may change between episodes are the keys of the env's
``VARIANT_DEFAULTS``; any other key (``robot_uids``...) is a constructor argument and must be the
same in every variant of a pool.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import sapien
import torch

PARK_Y = 3.0  # parked objects lie on the floor at y = 3 m (the table spans |y| < 1.2 m)
PARK_SPACING = 0.3


class VariantPoolMixin:
    """Mixin for ManiSkill ``BaseEnv`` subclasses: a pool of variants, one drawn per episode.

    Subclasses list their per-episode parameters and defaults in ``VARIANT_DEFAULTS``, call
    :meth:`_pool_init` first thing in ``__init__`` and :meth:`_draw_variants` at the start of
    ``_initialize_episode``; :meth:`_param` then gives a parameter's value per parallel env.
    """

    VARIANT_DEFAULTS: dict[str, Any] = {}

    def _pool_init(self, variants: Sequence[dict] | None, variant_names: Sequence[str] | None, kwargs: dict) -> dict:
        """Set up the pool; returns the keyword arguments left for the ManiSkill constructor."""
        kwargs = dict(kwargs)
        if variants is None:  # plain keyword arguments: a pool of one
            variants = [{k: kwargs.pop(k) for k in list(kwargs) if k in self.VARIANT_DEFAULTS}]
        if not variants:
            raise ValueError(f"{type(self).__name__}: the variant pool is empty")
        pool, shared = [], None
        for v in variants:
            per = {k: v[k] for k in v if k in self.VARIANT_DEFAULTS}
            rest = {k: v[k] for k in v if k not in self.VARIANT_DEFAULTS}
            if shared is None:
                shared = rest
            elif rest != shared:
                raise ValueError(
                    f"{type(self).__name__}: the variants of one split must share {sorted(set(rest) | set(shared))} "
                    f"(only {sorted(self.VARIANT_DEFAULTS)} can change between episodes); got {shared} and {rest}"
                )
            pool.append({**self.VARIANT_DEFAULTS, **per})
        for key in shared or {}:
            if key in kwargs and kwargs[key] != shared[key]:
                raise ValueError(
                    f"{type(self).__name__}: {key}={kwargs[key]!r} conflicts with the variants' {shared[key]!r}"
                )
        kwargs.update(shared or {})
        names = list(variant_names) if variant_names is not None else [f"variant{i}" for i in range(len(pool))]
        if len(names) != len(pool):
            raise ValueError(f"{len(names)} variant names for {len(pool)} variants")
        self.variant_pool: list[dict[str, Any]] = pool
        self.variant_names: list[str] = names
        self.variant_index: torch.Tensor | None = None
        self._param_cache: dict[str, torch.Tensor] = {}
        for v in pool:
            self._check_variant(v)
        return kwargs

    def _check_variant(self, variant: dict[str, Any]) -> None:
        """Raise ``ValueError`` for parameter values the task cannot use (override per task)."""

    @property
    def per_episode_variants(self) -> bool:
        """True on the CPU backend: a new variant every episode; False on the GPU backend (fixed per sub-env)."""
        return self.num_envs == 1

    def _fixed_assignment(self) -> torch.Tensor:
        """Variant of each parallel env on the GPU backend: round-robin over the pool."""
        return torch.arange(self.num_envs) % len(self.variant_pool)

    def _draw_variants(self, env_idx: torch.Tensor) -> torch.Tensor:
        """Draw the variant of each env being reset (CPU); the fixed assignment on the GPU backend."""
        if self.variant_index is None:
            self.variant_index = self._fixed_assignment().to(self.device)
        if self.per_episode_variants and len(self.variant_pool) > 1:
            drawn = [int(self._batched_episode_rng[int(i)].randint(len(self.variant_pool))) for i in env_idx.tolist()]
            self.variant_index[env_idx] = torch.tensor(drawn, device=self.device)
        return self.variant_index[env_idx]

    def _param(self, key: str, env_idx: torch.Tensor | None = None) -> torch.Tensor:
        """Value of a (numeric) variant parameter per env (all envs, or ``env_idx``)."""
        table = self._param_cache.get(key)
        if table is None:
            table = torch.as_tensor([float(v[key]) for v in self.variant_pool], dtype=torch.float32, device=self.device)
            self._param_cache[key] = table
        idx = self.variant_index if env_idx is None else self.variant_index[env_idx]
        return table[idx]

    def variant_episode_steps(self) -> torch.Tensor | None:
        """Episode length of each env's current variant (the ``max_steps`` variant parameter), or ``None``.

        Families whose variants have different time limits (ManiSkill's RotateValve levels: 80 to 300
        steps) list ``max_steps`` in ``VARIANT_DEFAULTS``; :class:`~drs_torchrl.envs.maniskill.ManiSkillEnv`
        then truncates each episode at its variant's limit (the env id's own limit is the longest).
        """
        if "max_steps" not in self.VARIANT_DEFAULTS or self.variant_index is None:
            return None
        return self._param("max_steps")

    @property
    def current_variant(self) -> str:
        """Name of the variant of the first parallel env (on the CPU backend: of this episode)."""
        return self.variant_names[int(self.variant_index[0])]


# ----------------------------------------------------------------------------------- objects
@dataclass(frozen=True)
class ObjectSpec:
    """A primitive object made with ManiSkill's actor builder (no downloaded assets).

    ``shape``: ``"box"`` (``size`` = 3 half extents), ``"cylinder"`` (radius, half height; stands
    upright), ``"sphere"`` (radius), ``"capsule"`` (radius, half length of the axis; lies along x).
    """

    shape: str
    size: tuple[float, ...]

    @classmethod
    def make(cls, shape: str, size) -> ObjectSpec:
        size = tuple(float(s) for s in (size if isinstance(size, (list, tuple)) else [size]))
        need = {"box": 3, "cube": 1, "cylinder": 2, "sphere": 1, "capsule": 2}
        if shape not in need:
            raise ValueError(f"object shape {shape!r} is not one of {sorted(need)}")
        if len(size) != need[shape]:
            raise ValueError(f"a {shape} takes {need[shape]} size value(s), got {list(size)}")
        if shape == "cube":
            shape, size = "box", size * 3
        if min(size) <= 0:
            raise ValueError(f"object sizes must be > 0, got {list(size)}")
        return cls(shape, size)

    @property
    def rest_height(self) -> float:
        """Height of the centre above the surface the object rests on (upright, unrotated)."""
        return {"box": lambda s: s[2], "cylinder": lambda s: s[1], "sphere": lambda s: s[0], "capsule": lambda s: s[0]}[
            self.shape
        ](self.size)

    @property
    def half_extent(self) -> tuple[float, float, float]:
        s = self.size
        return {
            "box": lambda: s,
            "cylinder": lambda: (s[0], s[0], s[1]),
            "sphere": lambda: (s[0],) * 3,
            "capsule": lambda: (s[0] + s[1], s[0], s[0]),
        }[self.shape]()

    def build(self, scene, name: str, color, *, scene_idxs=None, initial_pose: sapien.Pose | None = None):
        builder = scene.create_actor_builder()
        mat = sapien.render.RenderMaterial(base_color=list(color))
        if self.shape == "box":
            builder.add_box_collision(half_size=list(self.size))
            builder.add_box_visual(half_size=list(self.size), material=mat)
        elif self.shape == "cylinder":
            # SAPIEN's cylinder axis is x: turn it to z so that the cylinder stands on its base
            up = sapien.Pose(q=[np.cos(np.pi / 4), 0, np.sin(np.pi / 4), 0])
            builder.add_cylinder_collision(pose=up, radius=self.size[0], half_length=self.size[1])
            builder.add_cylinder_visual(pose=up, radius=self.size[0], half_length=self.size[1], material=mat)
        elif self.shape == "sphere":
            builder.add_sphere_collision(radius=self.size[0])
            builder.add_sphere_visual(radius=self.size[0], material=mat)
        elif self.shape == "capsule":
            builder.add_capsule_collision(radius=self.size[0], half_length=self.size[1])
            builder.add_capsule_visual(radius=self.size[0], half_length=self.size[1], material=mat)
        if scene_idxs is not None:
            builder.set_scene_idxs(scene_idxs)
        builder.set_initial_pose(initial_pose or sapien.Pose(p=[0, 0, self.rest_height]))
        return builder.build(name=name)


class ActorPool:
    """The actor that plays one role (e.g. "the object to pick") in each env, per variant.

    CPU backend: one actor per distinct spec, the unused ones parked on the floor beside the table.
    GPU backend: env ``i`` gets the spec of its fixed variant, the per-env actors merged into one.
    ``view`` is what task code reads (the active actor on CPU, the merged actor on GPU).
    """

    def __init__(
        self,
        env,
        role: str,
        specs_per_variant: Sequence[Any],
        build: Callable[..., Any],
        *,
        floor_z: float,
        park_slot: int = 0,
    ):
        from mani_skill.utils.structs.actor import Actor

        self.env, self.role = env, role
        self.specs = list(dict.fromkeys(specs_per_variant))  # distinct, in first-seen order
        self.spec_of_variant = torch.as_tensor([self.specs.index(s) for s in specs_per_variant], dtype=torch.long)
        self.floor_z = float(floor_z)
        self.gpu = env.num_envs > 1
        if not self.gpu:
            self.actors = []
            for j, spec in enumerate(self.specs):
                self.actors.append(
                    build(spec, name=f"{role}_{j}", scene_idxs=None, initial_pose=self._park_pose(park_slot + j, spec))
                )
            self.park_slots = [park_slot + j for j in range(len(self.specs))]
            self._active = 0
        else:
            assign = env._fixed_assignment()
            per_env = []
            for i in range(env.num_envs):
                spec = specs_per_variant[int(assign[i])]
                actor = build(spec, name=f"{role}_{i}", scene_idxs=[i], initial_pose=None)
                env.remove_from_state_dict_registry(actor)
                per_env.append(actor)
            self.merged = Actor.merge(per_env, name=role)
            env.add_to_state_dict_registry(self.merged)
            self.actors = per_env

    @property
    def num_slots(self) -> int:
        return len(self.specs) if not self.gpu else 0

    def _park_pose(self, slot: int, spec) -> sapien.Pose:
        h = spec.rest_height if hasattr(spec, "rest_height") else 0.05
        return sapien.Pose(p=[slot * PARK_SPACING, PARK_Y, self.floor_z + h + 1e-3])

    def spec(self, variant_idx: torch.Tensor) -> list:
        """Specs of the given variant indices."""
        return [self.specs[int(self.spec_of_variant[int(v)])] for v in variant_idx.reshape(-1).tolist()]

    def activate(self, env_idx: torch.Tensor, variant_idx: torch.Tensor, pose) -> None:
        """Put the variant's actor at ``pose`` (a batched Pose of ``len(env_idx)`` rows); park the rest."""
        from mani_skill.utils.structs.pose import Pose

        if self.gpu:
            self.merged.set_pose(pose)
            return
        active = int(self.spec_of_variant[int(variant_idx.reshape(-1)[0])])
        for j, actor in enumerate(self.actors):
            if j == active:
                actor.set_pose(pose)
            else:
                actor.set_pose(Pose.create(self._park_pose(self.park_slots[j], self.specs[j])))
        self._active = active

    @property
    def view(self):
        return self.merged if self.gpu else self.actors[self._active]
