"""ManiSkill task variants that drs-torchrl registers (the parameters that make a task family).

``PickCubeSized-v1``: ManiSkill's PickCube with the cube's half size as a constructor argument, so
that a reward learned on one cube size can be reused on another (Sec. 5: train/test variants of one
task family share the success criterion and differ in the object).
"""
from __future__ import annotations

from mani_skill.envs.tasks.tabletop.pick_cube import PickCubeEnv
from mani_skill.utils.registration import REGISTERED_ENVS, register_env


class PickCubeSizedEnv(PickCubeEnv):
    """PickCube with ``cube_half_size`` (metres) and ``goal_thresh`` (placed threshold) settable."""

    def __init__(self, *args, cube_half_size: float = 0.02, goal_thresh: float = 0.025, **kwargs):
        if not 0.005 <= cube_half_size <= 0.04:
            raise ValueError(f"cube_half_size={cube_half_size} m is outside the graspable 0.005-0.04 m range")
        self._variant_half_size = float(cube_half_size)
        self._variant_goal_thresh = float(goal_thresh)
        super().__init__(*args, **kwargs)

    def _load_scene(self, options: dict):
        # PickCubeEnv.__init__ sets these from its per-robot table before loading the scene
        self.cube_half_size = self._variant_half_size
        self.goal_thresh = self._variant_goal_thresh
        super()._load_scene(options)


if "PickCubeSized-v1" not in REGISTERED_ENVS:
    register_env("PickCubeSized-v1", max_episode_steps=50)(PickCubeSizedEnv)
