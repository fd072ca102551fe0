"""``RotateValveVariants-v1``: ManiSkill's RotateValve levels 0-4 (D'Claw turns a ROBEL valve) in one
scene, the level drawn per episode.

ManiSkill registers the five levels as five env ids (RotateValveLevel0..4-v1) that differ only in
the valve geometry and the goal: level 0 one fixed three-spoke valve (success at pi/2), level 1
three fixed valves with 3/4/5 evenly spaced spokes (pi), level 2 random spoke counts and angles
(pi), level 3 also random spoke length and thickness (pi), level 4 like 3 with a random turning
direction and a full turn (2 pi). Here one env builds ``valves_per_level`` valves of each level
of its pool once (level 0: one, level 1: its three; geometries drawn from ``geometry_seed``), parks
the unused ones beside the table, and draws a level per episode and a valve of that level.

Stage indicators (DrS Appendix A's Turn Faucet analogue): ``is_valve_turning`` (the valve turned
by more than ``turning_thresh`` radians in the commanded direction during the last control step)
and ``success`` (ManiSkill's: rotation beyond the level's goal).
"""

from __future__ import annotations

import numpy as np
import sapien
import torch
from mani_skill.envs.tasks.dexterity.rotate_valve import RotateValveEnv, sample_valve_angles
from mani_skill.utils.building.articulations import build_robel_valve
from mani_skill.utils.geometry.rotation_conversions import axis_angle_to_quaternion
from mani_skill.utils.registration import REGISTERED_ENVS, register_env
from mani_skill.utils.structs.articulation import Articulation
from mani_skill.utils.structs.link import Link
from mani_skill.utils.structs.pose import Pose

from drs_torchrl.envs.variants.pool import PARK_SPACING, PARK_Y, VariantPoolMixin

GOALS = {0: np.pi / 2, 1: np.pi, 2: np.pi, 3: np.pi, 4: 2 * np.pi}
LEVEL_STEPS = {0: 80, 1: 150, 2: 150, 3: 150, 4: 300}  # ManiSkill's RotateValveLevel{k}-v1 time limits


def valve_geometries(level: int, n: int, rng: np.random.RandomState) -> list[tuple[tuple[float, ...], float, float]]:
    """(spoke angles, spoke length scale, spoke radius scale) of the valves of a level."""
    if level == 0:
        return [((0.0, 2 * np.pi / 3, 4 * np.pi / 3), 1.0, 1.0)]
    if level == 1:
        return [(tuple(np.arange(0, 2 * np.pi, 2 * np.pi / k)), 1.0, 1.0) for k in (3, 4, 5)]
    out = []
    for _ in range(n):
        angles = tuple(sample_valve_angles(int(rng.randint(3, 6)), rng))
        scales = rng.randn(2) * 0.1 + 1 if level >= 3 else np.ones(2)
        out.append((angles, float(scales[0]), float(scales[1])))
    return out


class RotateValveVariantsEnv(VariantPoolMixin, RotateValveEnv):
    """RotateValve with ``level`` (0-4), ``turning_thresh`` (radians per control step) and ``max_steps`` per variant.

    ``max_steps`` (``None``: the level's ManiSkill limit, :data:`LEVEL_STEPS`) is the episode length of
    the variant; the env id's limit is the longest (300), and ``ManiSkillEnv`` truncates each episode
    at its own variant's (:meth:`VariantPoolMixin.variant_episode_steps`).
    """

    VARIANT_DEFAULTS = {"level": 0, "turning_thresh": 0.01, "max_steps": None}

    def __init__(
        self, *args, variants=None, variant_names=None, valves_per_level: int = 3, geometry_seed: int = 0, **kwargs
    ):
        kwargs = self._pool_init(variants, variant_names, kwargs)
        for v in self.variant_pool:
            if v["max_steps"] is None:
                v["max_steps"] = LEVEL_STEPS[int(v["level"])]
        self.valves_per_level, self.geometry_seed = int(valves_per_level), int(geometry_seed)
        first = int(self.variant_pool[0]["level"])
        super().__init__(*args, difficulty_level=first, **kwargs)

    def _check_variant(self, variant):
        if int(variant["level"]) not in GOALS:
            raise ValueError(f"level must be 0-4, got {variant['level']}")
        if variant["max_steps"] is not None and int(variant["max_steps"]) < 1:
            raise ValueError(f"max_steps must be >= 1 (or null for the level's own limit), got {variant['max_steps']}")

    # -------------------------------------------------------------------- scene
    def _load_articulations(self):
        rng = np.random.RandomState(self.geometry_seed)
        levels = [int(v["level"]) for v in self.variant_pool]
        geoms = {lvl: valve_geometries(lvl, self.valves_per_level, rng) for lvl in sorted(set(levels))}
        self._valves, self._valve_level, self._capsule_len = [], [], []
        self._park_poses = []
        if self.num_envs == 1:
            for lvl in sorted(geoms):
                for angles, s_len, s_rad in geoms[lvl]:
                    j = len(self._valves)
                    valve, cap = build_robel_valve(
                        self.scene,
                        valve_angles=angles,
                        name=f"valve_{j}",
                        radius_scale=s_len,
                        capsule_radius_scale=s_rad,
                    )
                    park = sapien.Pose(p=[j * PARK_SPACING, -PARK_Y, 0])  # fixed base: it may hover
                    valve.set_pose(Pose.create(park))
                    self._valves.append(valve)
                    self._valve_level.append(lvl)
                    self._capsule_len.append(cap)
                    self._park_poses.append(park)
            self._activate_valve(0)
        else:
            # GPU backend: env i gets one valve of its fixed level (round-robin over the pool)
            assign = self._fixed_assignment()
            per_env, links, caps = [], [], []
            for i in range(self.num_envs):
                lvl = levels[int(assign[i])]
                angles, s_len, s_rad = geoms[lvl][i % len(geoms[lvl])]
                valve, cap = build_robel_valve(
                    self.scene,
                    valve_angles=angles,
                    name=f"valve_station_{i}",
                    scene_idxs=[i],
                    radius_scale=s_len,
                    capsule_radius_scale=s_rad,
                )
                per_env.append(valve)
                links.append(valve.links_map["valve"])
                caps.append(cap)
            self.valve = Articulation.merge(per_env, "valve_station")
            self.valve_link = Link.merge(links, name="valve")
            self.capsule_lens = torch.as_tensor(caps, dtype=torch.float32, device=self.device)

    def _activate_valve(self, j: int) -> None:
        self._active_valve = j
        self.valve = self._valves[j]
        self.valve_link = self.valve.links_map["valve"]
        self.capsule_lens = torch.as_tensor([self._capsule_len[j]], dtype=torch.float32, device=self.device)

    def _initialize_actors(self, env_idx: torch.Tensor):
        with torch.device(self.device):
            b = len(env_idx)
            self._draw_variants(env_idx)
            level = self._param("level", env_idx).long()
            if self.num_envs == 1:
                lvl = int(level[0])
                options = [j for j, v_lvl in enumerate(self._valve_level) if v_lvl == lvl]
                self._activate_valve(options[int(self._batched_episode_rng[0].randint(len(options)))])
                for j, valve in enumerate(self._valves):
                    if j != self._active_valve:
                        valve.set_pose(Pose.create(self._park_poses[j]))
            self.table_scene.initialize(env_idx)
            direction = torch.ones(b)
            reverse = level >= 4
            if reverse.any():
                direction[reverse] = (1 - torch.randint(0, 2, (int(reverse.sum()),)) * 2).float()
            if (
                self.rotate_direction is None
                or not torch.is_tensor(self.rotate_direction)
                or len(self.rotate_direction) != self.num_envs
            ):
                self.rotate_direction = torch.ones(self.num_envs)
                self.rest_qpos = torch.zeros((self.num_envs, 1))
                self._prev_progress = torch.zeros(self.num_envs)
            self.rotate_direction[env_idx] = direction
            xyz = torch.zeros((b, 3))
            xyz[:, :2].uniform_(-0.02, 0.02)
            axis_angle = torch.zeros((b, 3))
            axis_angle[:, 2].uniform_(torch.pi / 6, torch.pi * 5 / 6)
            self.valve.set_pose(Pose.create_from_pq(xyz, axis_angle_to_quaternion(axis_angle)))
            qpos = torch.rand((b, 1)) * torch.pi * 2 - torch.pi
            self.valve.set_qpos(qpos)
            self.rest_qpos[env_idx] = qpos
            self._prev_progress[env_idx] = 0.0
            self.success_threshold = torch.as_tensor(
                [GOALS[int(v["level"])] for v in self.variant_pool], dtype=torch.float32
            )[self.variant_index.cpu()].to(self.device)

    rotate_direction = None

    # --------------------------------------------------------------- evaluation
    def _progress(self) -> torch.Tensor:
        """Rotation since the episode start in the commanded direction (radians)."""
        return (self.valve.qpos - self.rest_qpos)[:, 0] * self.rotate_direction

    def _before_control_step(self):
        super()._before_control_step()
        self._prev_progress = self._progress().clone()

    def evaluate(self, **kwargs) -> dict:
        rotation = (self.valve.qpos - self.rest_qpos)[:, 0]
        progress = rotation * self.rotate_direction
        turning = (progress - self._prev_progress) > self._param("turning_thresh")
        return {"success": progress > self.success_threshold, "is_valve_turning": turning, "valve_rotation": rotation}


if "RotateValveVariants-v1" not in REGISTERED_ENVS:
    register_env("RotateValveVariants-v1", max_episode_steps=max(LEVEL_STEPS.values()))(RotateValveVariantsEnv)
