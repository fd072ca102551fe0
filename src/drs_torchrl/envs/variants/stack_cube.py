"""``StackCubeSized-v1``: ManiSkill's StackCube with the two cubes' sizes as variant parameters.

Stage indicators (three stages, read from StackCube's ``evaluate``): ``is_cubeA_grasped``,
``is_cubeA_on_cubeB`` and ``success`` (A on B, A static, A released). With cubes of different
sizes, "A on B" means A's centre is ``hA + hB`` (+-5 mm) above B's and within B's half diagonal
(+5 mm) of it horizontally, which is StackCube's own test when both half sizes are 2 cm.
"""

from __future__ import annotations

import torch
from mani_skill.envs.tasks.tabletop.stack_cube import StackCubeEnv
from mani_skill.envs.utils import randomization
from mani_skill.utils.registration import REGISTERED_ENVS, register_env
from mani_skill.utils.scene_builder.table import TableSceneBuilder
from mani_skill.utils.structs.pose import Pose

from drs_torchrl.envs.variants.pool import ActorPool, ObjectSpec, VariantPoolMixin


class StackCubeSizedEnv(VariantPoolMixin, StackCubeEnv):
    """StackCube with ``cube_a_half_size`` (the cube to pick) and ``cube_b_half_size`` per variant."""

    VARIANT_DEFAULTS = {"cube_a_half_size": 0.02, "cube_b_half_size": 0.02}

    def __init__(self, *args, variants=None, variant_names=None, robot_uids=None, **kwargs):
        kwargs = self._pool_init(
            variants, variant_names, kwargs if robot_uids is None else {"robot_uids": robot_uids, **kwargs}
        )
        kwargs.setdefault("robot_uids", "panda")
        super().__init__(*args, **kwargs)

    def _check_variant(self, variant):
        for k in ("cube_a_half_size", "cube_b_half_size"):
            if not 0.01 <= float(variant[k]) <= 0.035:
                raise ValueError(f"{k}={variant[k]} m is outside the 0.01-0.035 m range of this task")

    @property
    def cubeA(self):
        return self.pool_a.view

    @property
    def cubeB(self):
        return self.pool_b.view

    def _load_scene(self, options: dict):
        self.table_scene = TableSceneBuilder(env=self, robot_init_qpos_noise=self.robot_init_qpos_noise)
        self.table_scene.build()
        floor = -self.table_scene.table_height
        specs_a = [ObjectSpec.make("cube", v["cube_a_half_size"]) for v in self.variant_pool]
        specs_b = [ObjectSpec.make("cube", v["cube_b_half_size"]) for v in self.variant_pool]

        def builder(color):
            return lambda spec, name, scene_idxs, initial_pose: spec.build(
                self.scene, name, color, scene_idxs=scene_idxs, initial_pose=initial_pose
            )

        self.pool_a = ActorPool(self, "cubeA", specs_a, builder((1, 0, 0, 1)), floor_z=floor)
        self.pool_b = ActorPool(
            self, "cubeB", specs_b, builder((0, 1, 0, 1)), floor_z=floor, park_slot=self.pool_a.num_slots
        )

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        with torch.device(self.device):
            b = len(env_idx)
            vidx = self._draw_variants(env_idx)
            self.table_scene.initialize(env_idx)
            ha, hb = self._param("cube_a_half_size", env_idx), self._param("cube_b_half_size", env_idx)
            xy = torch.rand((b, 2)) * 0.2 - 0.1
            sampler = randomization.UniformPlacementSampler(
                bounds=[[-0.1, -0.2], [0.1, 0.2]], batch_size=b, device=self.device
            )
            radius = float(torch.maximum(ha, hb).max()) * 2**0.5 + 0.001
            a_xy = xy + sampler.sample(radius, 100)
            b_xy = xy + sampler.sample(radius, 100, verbose=False)
            for pool, pxy, h in ((self.pool_a, a_xy, ha), (self.pool_b, b_xy, hb)):
                q = randomization.random_quaternions(b, lock_x=True, lock_y=True, lock_z=False)
                pool.activate(env_idx, vidx, Pose.create_from_pq(p=torch.cat([pxy, h[:, None]], 1), q=q))
            # StackCube's users (its dense reward, the motion planner) read cube_half_size[2] * 2 as
            # the height of A's centre above B's: per env, [hA, hA, (hA + hB) / 2]
            ha_all, hb_all = self._param("cube_a_half_size"), self._param("cube_b_half_size")
            self.cube_half_size = torch.stack([ha_all, ha_all, (ha_all + hb_all) / 2])

    def evaluate(self):
        ha, hb = self._param("cube_a_half_size"), self._param("cube_b_half_size")
        offset = self.cubeA.pose.p - self.cubeB.pose.p
        xy_ok = torch.linalg.norm(offset[..., :2], axis=1) <= hb * 2**0.5 + 0.005
        z_ok = torch.abs(offset[..., 2] - (ha + hb)) <= 0.005
        on_b = xy_ok & z_ok
        static = self.cubeA.is_static(lin_thresh=1e-2, ang_thresh=0.5)
        grasped = self.agent.is_grasping(self.cubeA)
        return {
            "is_cubeA_grasped": grasped,
            "is_cubeA_on_cubeB": on_b,
            "is_cubeA_static": static,
            "success": on_b & static & ~grasped,
        }


if "StackCubeSized-v1" not in REGISTERED_ENVS:
    register_env("StackCubeSized-v1", max_episode_steps=50)(StackCubeSizedEnv)
