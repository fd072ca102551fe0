"""The paper's asset-backed task families (DrS Sec. 5.1, Appendix A), restricted to a split's models.

These need ManiSkill assets that must be downloaded first (``python -m
mani_skill.utils.download_asset <id>``); ``drs_torchrl.envs.doctor`` checks that before any env is
built, so a missing asset fails at once with the command instead of ManiSkill's interactive
prompt. On the CPU backend ManiSkill rebuilds these scenes at every reset (a new model per
episode, its ``reconfiguration_freq=1`` default for one env), so the per-episode variant is the
model ManiSkill loads, drawn from the models of the split's variants.

* ``PickSingleYCBSplit-v1``: PickSingleYCB-v1 on a subset of the YCB objects. Stage indicators as
  Appendix A's Pick-and-Place: ``is_grasped``, ``is_obj_placed`` (within ``placed_thresh``; 0 =
  ``goal_thresh``), ``success`` = within ``goal_thresh``, robot static and object static (< 3 cm/s over
  the last control step).
* ``TurnFaucetSplit-v1``: TurnFaucet-v1 on a subset of its 60 PartNet-Mobility faucets.
  Indicators (Appendix A, Turn Faucet): ``is_handle_moving`` (the target joint turns towards its
  goal faster than ``moving_thresh`` = 0.01 rad/s) and ``success`` (90% of the joint range).
* ``OpenCabinetDoorSplit-v1``: OpenCabinetDoor-v1 (Fetch) on a subset of the cabinets.
  Indicators (Appendix A, Open Cabinet Door): ``is_handle_grasped``, ``open_enough`` (the door's
  joint beyond ``open_frac`` = 90% of its range) and ``success`` = open enough and the door static
  (< 0.1 m/s, < 1 rad/s); ``is_door_static`` is reported too.

Each variant is ``{"model_ids": [...]}`` (faucets and cabinets: PartNet-Mobility ids) or, for YCB,
``{"model_split": "train" | "test"}`` (the YCB object list ships with the download, so the split
is a rule on the sorted ids, see :func:`ycb_split`) or ``{"model_ids": [...]}``.
"""

from __future__ import annotations

import numpy as np
import torch
from mani_skill.envs.tasks.mobile_manipulation.open_cabinet_drawer import OpenCabinetDoorEnv
from mani_skill.envs.tasks.tabletop.pick_single_ycb import PickSingleYCBEnv
from mani_skill.envs.tasks.tabletop.turn_faucet import TurnFaucetEnv
from mani_skill.utils.registration import REGISTERED_ENVS, register_env

from drs_torchrl.envs.variants.pick import placed_threshold
from drs_torchrl.envs.variants.pool import VariantPoolMixin


def ycb_split(model_ids, split: str) -> list[str]:
    """Held-out YCB objects: every fourth object of the sorted id list is a test object."""
    ids = sorted(model_ids)
    if split not in ("train", "test"):
        raise ValueError(f"model_split must be 'train' or 'test', got {split!r}")
    return [m for i, m in enumerate(ids) if (i % 4 == 3) == (split == "test")]


class _ModelSplitMixin(VariantPoolMixin):
    """Restrict an asset-backed env's model list to the union of its variants' models."""

    def _variant_models(self, variant: dict, all_ids) -> list[str]:
        ids = [str(m) for m in variant.get("model_ids") or []]
        unknown = sorted(set(ids) - {str(m) for m in all_ids})
        if unknown:
            raise ValueError(f"{type(self).__name__}: unknown model ids {unknown}")
        return ids

    def _restrict_models(self) -> None:
        if getattr(self, "_models_of_variant", None) is None:
            self._models_of_variant = [self._variant_models(v, self.all_model_ids) for v in self.variant_pool]
            union = list(dict.fromkeys(m for ms in self._models_of_variant for m in ms))
            if not union:
                raise ValueError(f"{type(self).__name__}: the variants name no models")
            self.all_model_ids = np.array(union)

    def _note_loaded_models(self, names: list[str]) -> None:
        """Variant of each env from the model ManiSkill loaded (actor names are '<model id>-<env>')."""
        idx = []
        for name in names:
            model = name.rsplit("-", 1)[0]
            idx.append(next(i for i, ms in enumerate(self._models_of_variant) if model in ms))
        self.variant_index = torch.as_tensor(idx, device=self.device)

    def _draw_variants(self, env_idx):  # the model (hence the variant) is drawn at reconfiguration
        return self.variant_index[env_idx]


class PickSingleYCBSplitEnv(_ModelSplitMixin, PickSingleYCBEnv):
    VARIANT_DEFAULTS = {
        "model_ids": None,
        "model_split": None,
        "goal_thresh": 0.025,
        "placed_thresh": 0.0,
        "object_static_thresh": 0.03,
    }

    def __init__(self, *args, variants=None, variant_names=None, robot_uids=None, **kwargs):
        kwargs = self._pool_init(
            variants, variant_names, kwargs if robot_uids is None else {"robot_uids": robot_uids, **kwargs}
        )
        kwargs.setdefault("robot_uids", "panda")
        super().__init__(*args, **kwargs)

    def _variant_models(self, variant, all_ids):
        if variant.get("model_split"):
            return ycb_split(all_ids, variant["model_split"])
        return super()._variant_models(variant, all_ids)

    def _load_scene(self, options: dict):
        self._restrict_models()
        super()._load_scene(options)
        self._note_loaded_models([o.name for o in self._objs])

    def _initialize_episode(self, env_idx, options):
        super()._initialize_episode(env_idx, options)
        if getattr(self, "_obj_prev_p", None) is None or len(self._obj_prev_p) != self.num_envs:
            self._obj_prev_p = self.obj.pose.p.clone()
        self._obj_prev_p[env_idx] = self.obj.pose.p[env_idx]

    def _before_control_step(self):
        super()._before_control_step()
        self._obj_prev_p = self.obj.pose.p.clone()

    def evaluate(self):
        info = super().evaluate()
        obj_to_goal = torch.linalg.norm(info["obj_to_goal_pos"], axis=1)
        at_goal = obj_to_goal <= self._param("goal_thresh")
        info["is_obj_placed"] = obj_to_goal <= placed_threshold(self)  # the stage indicator; success keeps goal_thresh
        thresh = self._param("object_static_thresh")
        # speed over the last control step: PhysX reports velocity for a squeezed object that does not move
        speed = torch.linalg.norm(self.obj.pose.p - self._obj_prev_p, axis=1) * self.control_freq
        info["is_obj_static"] = (speed <= thresh) | (thresh <= 0)
        info["success"] = at_goal & info["is_robot_static"] & info["is_obj_static"]
        return info


class TurnFaucetSplitEnv(_ModelSplitMixin, TurnFaucetEnv):
    VARIANT_DEFAULTS = {"model_ids": None, "moving_thresh": 0.01}

    def __init__(self, *args, variants=None, variant_names=None, robot_uids=None, **kwargs):
        kwargs = self._pool_init(
            variants, variant_names, kwargs if robot_uids is None else {"robot_uids": robot_uids, **kwargs}
        )
        kwargs.setdefault("robot_uids", "panda")
        super().__init__(*args, **kwargs)

    def _load_scene(self, options: dict):
        self._restrict_models()
        super()._load_scene(options)
        self._note_loaded_models([f.name for f in self._faucets])

    def evaluate(self):
        info = super().evaluate()
        # the goal angle is above the initial one (90% of the joint range), so "towards it" is qvel > 0
        qvel = self.target_switch_link.joint.qvel.reshape(-1)
        info["is_handle_moving"] = qvel > self._param("moving_thresh")
        return info


class OpenCabinetDoorSplitEnv(_ModelSplitMixin, OpenCabinetDoorEnv):
    VARIANT_DEFAULTS = {"model_ids": None}

    def __init__(self, *args, variants=None, variant_names=None, open_frac: float = 0.9, **kwargs):
        kwargs = self._pool_init(variants, variant_names, kwargs)
        if not 0 < open_frac <= 1:
            raise ValueError(f"open_frac must be in (0, 1], got {open_frac}")
        self.min_open_frac = float(open_frac)  # read by ManiSkill when it sets the door's target angle
        super().__init__(*args, **kwargs)

    def _load_cabinets(self, joint_types):
        self._restrict_models()
        super()._load_cabinets(joint_types)
        self._note_loaded_models([c.name for c in self._cabinets])

    def evaluate(self):
        info = super().evaluate()
        open_enough = info["open_enough"].reshape(-1)
        info["open_enough"] = open_enough
        info["is_handle_grasped"] = self.agent.is_grasping(self.handle_link)
        link = self.handle_link
        info["is_door_static"] = (torch.linalg.norm(link.angular_velocity, axis=1) <= 1) & (
            torch.linalg.norm(link.linear_velocity, axis=1) <= 0.1
        )
        info["success"] = open_enough & info["is_door_static"]
        return info


for _id, _cls, _steps, _assets in (
    ("PickSingleYCBSplit-v1", PickSingleYCBSplitEnv, 50, ["ycb"]),
    ("TurnFaucetSplit-v1", TurnFaucetSplitEnv, 200, ["partnet_mobility_faucet"]),
    ("OpenCabinetDoorSplit-v1", OpenCabinetDoorSplitEnv, 100, ["partnet_mobility_cabinet"]),
):
    if _id not in REGISTERED_ENVS:
        register_env(_id, max_episode_steps=_steps, asset_download_ids=_assets)(_cls)
