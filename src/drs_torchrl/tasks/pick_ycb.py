"""``pick_ycb``: Panda picks a YCB object and holds it at a goal (ManiSkill PickSingleYCB-v1).

The paper's Pick-and-Place family (Sec. 5.1, Appendix A) with YCB objects. Needs the YCB assets:
``python -m mani_skill.utils.download_asset ycb -y``; without them the env fails at once with that
command. The object list comes with the download, so the held-out split is a rule on the sorted
ids (``envs.variants.assets.ycb_split``): every fourth object is a test object, the rest (about
three quarters) are training objects; every episode loads one object of the split.

Stage indicators (Appendix A): ``is_grasped``, ``is_obj_placed`` (2.5 cm; ``placed_thresh``, by default ``goal_thresh``),
``success`` = within ``goal_thresh``, robot static and object static (< 3 cm/s).
"""

from drs_torchrl.tasks import TaskFamily, register_family

register_family(
    TaskFamily(
        name="pick_ycb",
        env_id="PickSingleYCBSplit-v1",
        description="Panda picks a YCB object and holds it at a goal (needs the ycb assets)",
        stage_keys=("is_grasped", "is_obj_placed", "success"),
        info_keys=("is_robot_static", "is_obj_static"),
        variants={"ycb_train": {"model_split": "train"}, "ycb_test": {"model_split": "test"}},
        train_variants=("ycb_train",),
        test_variants=("ycb_test",),
        pooled=True,
        extra={"assets": "ycb"},
    )
)
