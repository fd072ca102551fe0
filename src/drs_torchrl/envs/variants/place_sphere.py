"""``PlaceSphereSized-v1``: ManiSkill's PlaceSphere with the sphere's radius as a variant parameter.

Stage indicators (three stages, read from PlaceSphere's ``evaluate``): ``is_obj_grasped``,
``is_obj_on_bin`` and ``success`` (on the bin, sphere static, released). The bin's inner square
has a 2 cm half side; a sphere of radius ``r`` resting on the bin's floor can sit anywhere within
``2 cm - r`` of its centre, so "on bin" allows that much (+5 mm) horizontally, which for
PlaceSphere's own 2 cm sphere is its original 5 mm test. Radii from 1 to 2 cm fit the bin.
"""

from __future__ import annotations

import numpy as np
import torch
from mani_skill.envs.tasks.tabletop.place_sphere import PlaceSphereEnv
from mani_skill.utils.registration import REGISTERED_ENVS, register_env
from mani_skill.utils.scene_builder.table import TableSceneBuilder
from mani_skill.utils.structs.pose import Pose

from drs_torchrl.envs.variants.pool import ActorPool, ObjectSpec, VariantPoolMixin


class PlaceSphereSizedEnv(VariantPoolMixin, PlaceSphereEnv):
    """PlaceSphere with ``sphere_radius`` (metres) per variant."""

    VARIANT_DEFAULTS = {"sphere_radius": 0.02}

    def __init__(self, *args, variants=None, variant_names=None, robot_uids=None, **kwargs):
        kwargs = self._pool_init(
            variants, variant_names, kwargs if robot_uids is None else {"robot_uids": robot_uids, **kwargs}
        )
        kwargs.setdefault("robot_uids", "panda")
        super().__init__(*args, **kwargs)

    def _check_variant(self, variant):
        r = float(variant["sphere_radius"])
        if not 0.01 <= r <= self.inner_side_half_len:
            raise ValueError(f"sphere_radius={r} m: the bin takes radii from 0.01 to {self.inner_side_half_len} m")

    @property
    def obj(self):
        return self.sphere_pool.view

    def _load_scene(self, options: dict):
        self.table_scene = TableSceneBuilder(env=self, robot_init_qpos_noise=self.robot_init_qpos_noise)
        self.table_scene.build()
        specs = [ObjectSpec.make("sphere", v["sphere_radius"]) for v in self.variant_pool]
        color = np.array([12, 42, 160, 255]) / 255
        self.sphere_pool = ActorPool(
            self,
            "sphere",
            specs,
            lambda spec, name, scene_idxs, initial_pose: spec.build(
                self.scene, name, color, scene_idxs=scene_idxs, initial_pose=initial_pose
            ),
            floor_z=-self.table_scene.table_height,
        )
        self.bin = self._build_bin(self.inner_side_half_len)

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        with torch.device(self.device):
            b = len(env_idx)
            vidx = self._draw_variants(env_idx)
            self.table_scene.initialize(env_idx)
            r = self._param("sphere_radius", env_idx)
            xyz = torch.zeros((b, 3))
            xyz[:, 0] = torch.rand(b) * 0.05 - 0.1  # the sphere in x [-0.1, -0.05]
            xyz[:, 1] = torch.rand(b) * 0.2 - 0.1
            xyz[:, 2] = r
            self.sphere_pool.activate(env_idx, vidx, Pose.create_from_pq(p=xyz, q=[1, 0, 0, 0]))
            pos = torch.zeros((b, 3))
            pos[:, 0] = torch.rand(b) * 0.1  # the bin in x [0, 0.1]
            pos[:, 1] = torch.rand(b) * 0.2 - 0.1
            pos[:, 2] = self.block_half_size[0]
            self.bin.set_pose(Pose.create_from_pq(p=pos, q=[1, 0, 0, 0]))
            # PlaceSphere's dense reward reads self.radius: per env here
            self.radius = self._param("sphere_radius")

    def evaluate(self):
        r = self._param("sphere_radius")
        offset = self.obj.pose.p - self.bin.pose.p
        xy_ok = torch.linalg.norm(offset[..., :2], axis=1) <= (self.inner_side_half_len - r) + 0.005
        z_ok = torch.abs(offset[..., 2] - r - self.block_half_size[0]) <= 0.005
        on_bin = xy_ok & z_ok
        static = self.obj.is_static(lin_thresh=1e-2, ang_thresh=0.5)
        grasped = self.agent.is_grasping(self.obj)
        return {
            "is_obj_grasped": grasped,
            "is_obj_on_bin": on_bin,
            "is_obj_static": static,
            "success": on_bin & static & ~grasped,
        }


if "PlaceSphereSized-v1" not in REGISTERED_ENVS:
    register_env("PlaceSphereSized-v1", max_episode_steps=50)(PlaceSphereSizedEnv)
