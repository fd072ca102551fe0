"""Pick-and-place variants (DrS paper, Appendix A "Pick-and-Place"): ManiSkill's PickCube scene
with the object, the "placed" threshold and the robot as parameters.

* ``PickObject-v1``: pick an object of a given primitive shape and size and hold it at a goal.
  Stage indicators: ``is_grasped`` (both fingers touch the object with non-zero force),
  ``is_obj_placed`` (object within ``placed_thresh`` of the goal; 0, the default, means ``goal_thresh``,
  2.5 cm) and ``success`` = object within ``goal_thresh``, robot static (joint speeds < 0.2 rad/s)
  and object static (< 3 cm/s), as Appendix A.
  The object's speed is its displacement over the last control step: PhysX reports a few cm/s
  (and rad/s) of velocity for an object squeezed between the fingers even when it does not move.
  Works with the robots ManiSkill's PickCube supports without downloads (``panda``, ``fetch``,
  ``so100``); each robot keeps ManiSkill's PickCube workspace (spawn region, goal heights).
  :meth:`PickObjectEnv.task_observation` is a robot-agnostic view of the task for rewards that
  must transfer between robots.
* ``PickCubeSized-v1``: the ``pick_cube`` family's env, PickCube with ``cube_half_size``,
  ``goal_thresh`` and ``placed_thresh`` per variant; success is ManiSkill's (within ``goal_thresh``
  and robot static), and the observation is PickCube's (42 numbers with the Panda).

``placed_thresh`` moves the "placed" stage indicator alone, as the paper's threshold ablation does
(Sec. 5.4.1: "the task success condition is unchanged"); ``goal_thresh`` moves success too.

Both draw a variant per episode from the pool they are given (see ``pool.py``).
"""

from __future__ import annotations

import torch
from mani_skill.envs.tasks.tabletop.pick_cube import PickCubeEnv
from mani_skill.envs.utils import randomization
from mani_skill.utils.building import actors
from mani_skill.utils.registration import REGISTERED_ENVS, register_env
from mani_skill.utils.scene_builder.table import TableSceneBuilder
from mani_skill.utils.structs.pose import Pose

from drs_torchrl.envs.variants.pool import ActorPool, ObjectSpec, VariantPoolMixin


def placed_threshold(env) -> torch.Tensor:
    """The "placed" stage indicator's distance per env: ``placed_thresh``, or ``goal_thresh`` where it is 0."""
    goal, placed = env._param("goal_thresh"), env._param("placed_thresh")
    return torch.where(placed > 0, placed, goal)


OBJECT_COLORS = [(0.85, 0.1, 0.1, 1), (0.1, 0.3, 0.85, 1), (0.9, 0.6, 0.1, 1), (0.5, 0.1, 0.7, 1), (0.1, 0.6, 0.5, 1)]


class PickObjectEnv(VariantPoolMixin, PickCubeEnv):
    """PickCube with a pool of objects (shape and size) and a configurable "placed" threshold.

    Variant parameters (per episode): ``object_shape`` (``box``, ``cube``, ``cylinder``, ``sphere``,
    ``capsule``), ``object_size`` (see :class:`~drs_torchrl.envs.variants.pool.ObjectSpec`),
    ``goal_thresh`` (metres, success's distance to the goal), ``placed_thresh`` (metres, the "placed"
    stage indicator's; ``0`` = ``goal_thresh``) and ``object_static_thresh`` (m/s; ``0`` drops the
    object-static condition from success). ``robot_uids`` is a constructor argument.
    """

    VARIANT_DEFAULTS = {
        "object_shape": "cube",
        "object_size": 0.02,
        "goal_thresh": 0.025,
        "placed_thresh": 0.0,
        "object_static_thresh": 0.03,
    }
    GRASPABLE = (0.005, 0.04)  # half widths the grippers can close on (metres)

    def __init__(self, *args, variants=None, variant_names=None, robot_uids=None, **kwargs):
        kwargs = self._pool_init(
            variants, variant_names, kwargs if robot_uids is None else {"robot_uids": robot_uids, **kwargs}
        )
        kwargs.setdefault("robot_uids", "panda")
        super().__init__(*args, **kwargs)

    def _object_spec(self, variant: dict) -> ObjectSpec:
        return ObjectSpec.make(variant["object_shape"], variant["object_size"])

    def _check_variant(self, variant):
        spec = self._object_spec(variant)
        lo, hi = self.GRASPABLE
        if not lo <= min(spec.half_extent[:2]) <= hi:
            raise ValueError(
                f"object {spec.shape} {list(spec.size)}: its narrowest horizontal half width "
                f"{min(spec.half_extent[:2])} m is outside the graspable {lo}-{hi} m range"
            )
        if float(variant["goal_thresh"]) <= 0:
            raise ValueError(f"goal_thresh must be > 0, got {variant['goal_thresh']}")
        if float(variant["placed_thresh"]) < 0:
            raise ValueError(f"placed_thresh must be >= 0 (0: the same as goal_thresh), got {variant['placed_thresh']}")

    # -------------------------------------------------------------------- scene
    @property
    def cube(self):
        """The object of this episode (name kept from PickCube, which the motion planner reads)."""
        return self.obj_pool.view

    @property
    def obj(self):
        return self.obj_pool.view

    def _load_scene(self, options: dict):
        self.table_scene = TableSceneBuilder(self, robot_init_qpos_noise=self.robot_init_qpos_noise)
        self.table_scene.build()
        specs = [self._object_spec(v) for v in self.variant_pool]

        def build(spec, name, scene_idxs, initial_pose):
            color = OBJECT_COLORS[specs.index(spec) % len(OBJECT_COLORS)]
            return spec.build(self.scene, name, color, scene_idxs=scene_idxs, initial_pose=initial_pose)

        self.obj_pool = ActorPool(self, "object", specs, build, floor_z=-self.table_scene.table_height)
        self.goal_site = actors.build_sphere(
            self.scene,
            radius=max(float(v["goal_thresh"]) for v in self.variant_pool),
            color=[0, 1, 0, 1],
            name="goal_site",
            body_type="kinematic",
            add_collision=False,
        )
        self._hidden_objects.append(self.goal_site)

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        with torch.device(self.device):
            b = len(env_idx)
            vidx = self._draw_variants(env_idx)
            self.table_scene.initialize(env_idx)
            rest = torch.tensor([s.rest_height for s in self.obj_pool.spec(vidx)])
            xyz = torch.zeros((b, 3))
            xyz[:, :2] = torch.rand((b, 2)) * self.cube_spawn_half_size * 2 - self.cube_spawn_half_size
            xyz[:, 0] += self.cube_spawn_center[0]
            xyz[:, 1] += self.cube_spawn_center[1]
            xyz[:, 2] = rest
            qs = randomization.random_quaternions(b, lock_x=True, lock_y=True)
            self.obj_pool.activate(env_idx, vidx, Pose.create_from_pq(xyz, qs))
            goal = torch.zeros((b, 3))
            goal[:, :2] = torch.rand((b, 2)) * self.cube_spawn_half_size * 2 - self.cube_spawn_half_size
            goal[:, 0] += self.cube_spawn_center[0]
            goal[:, 1] += self.cube_spawn_center[1]
            goal[:, 2] = torch.rand(b) * self.max_goal_height + rest
            self.goal_site.set_pose(Pose.create_from_pq(goal))
            self._sync_attributes()
            if getattr(self, "_obj_prev_p", None) is None or len(self._obj_prev_p) != self.num_envs:
                self._obj_prev_p = torch.zeros((self.num_envs, 3))
            self._obj_prev_p[env_idx] = xyz

    def _before_control_step(self):
        super()._before_control_step()
        self._obj_prev_p = self.obj.pose.p.clone()

    def object_speed(self) -> torch.Tensor:
        """Object speed over the last control step (m/s), ``(num_envs,)``; 0 right after a reset."""
        return torch.linalg.norm(self.obj.pose.p - self._obj_prev_p, axis=1) * self.control_freq

    def _sync_attributes(self):
        """Scalar views of the current variant on the CPU backend (what PickCube's users read)."""
        if self.num_envs == 1:
            spec = self.obj_pool.spec(self.variant_index)[0]
            self.goal_thresh = float(self._param("goal_thresh")[0])
            self.object_half_extent = spec.half_extent

    # --------------------------------------------------------------- evaluation
    def evaluate(self):
        obj = self.obj
        obj_to_goal = torch.linalg.norm(self.goal_site.pose.p - obj.pose.p, axis=1)
        at_goal = obj_to_goal <= self._param("goal_thresh")
        is_obj_placed = obj_to_goal <= placed_threshold(self)
        is_grasped = self.agent.is_grasping(obj)
        is_robot_static = self.agent.is_static(0.2)
        info = {"is_obj_placed": is_obj_placed, "is_robot_static": is_robot_static, "is_grasped": is_grasped}
        success = at_goal & is_robot_static
        if "object_static_thresh" in self.VARIANT_DEFAULTS:
            thresh = self._param("object_static_thresh")
            info["is_obj_static"] = (self.object_speed() <= thresh) | (thresh <= 0)
            success = success & info["is_obj_static"]
        return {"success": success, **info}

    @property
    def workspace_origin(self) -> torch.Tensor:
        """Centre of the object spawn region on the table top: the origin of :meth:`task_observation`."""
        return torch.tensor([self.cube_spawn_center[0], self.cube_spawn_center[1], 0.0], device=self.device)

    def task_observation(self) -> torch.Tensor:
        """Robot-agnostic task state, ``(num_envs, 19)``, positions in the workspace frame.

        Object pose (position, quaternion), goal position, TCP position, TCP-to-object and
        object-to-goal vectors: what a pick-and-place reward needs, with nothing about the robot's
        joints, so a reward learned with one robot can be reused with another.
        """
        o = self.workspace_origin
        obj_p, obj_q = self.obj.pose.p, self.obj.pose.q
        goal, tcp = self.goal_site.pose.p, self.agent.tcp_pose.p
        return torch.cat([obj_p - o, obj_q, goal - o, tcp - o, obj_p - tcp, goal - obj_p], dim=-1).float()


class PickCubeSizedEnv(PickObjectEnv):
    """PickCube with ``cube_half_size``, ``goal_thresh`` and ``placed_thresh`` (metres) per variant.

    Success is ManiSkill's PickCube success (within ``goal_thresh`` and robot static), and
    ``cube_half_size`` / ``goal_thresh`` read as the current episode's values on the CPU backend.
    """

    VARIANT_DEFAULTS = {"cube_half_size": 0.02, "goal_thresh": 0.025, "placed_thresh": 0.0}

    def _object_spec(self, variant):
        return ObjectSpec.make("cube", variant["cube_half_size"])

    def _check_variant(self, variant):
        h = float(variant["cube_half_size"])
        if not 0.005 <= h <= 0.04:
            raise ValueError(f"cube_half_size={h} m is outside the graspable 0.005-0.04 m range")
        super()._check_variant(variant)

    def _sync_attributes(self):
        super()._sync_attributes()
        if self.num_envs == 1:
            self.cube_half_size = float(self._param("cube_half_size")[0])


for _id, _cls in (("PickObject-v1", PickObjectEnv), ("PickCubeSized-v1", PickCubeSizedEnv)):
    if _id not in REGISTERED_ENVS:
        register_env(_id, max_episode_steps=50)(_cls)
