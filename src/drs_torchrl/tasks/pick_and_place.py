"""``pick_and_place``: Panda picks an object and holds it at a goal; the object varies in shape and size.

DrS paper, Sec. 5.1 and Appendix A ("Pick-and-Place"): rewards are learned on 74 YCB objects and
reused on ~1600 EGAD objects, two object sets with nothing in common. Without downloaded assets
this family makes its objects from primitives with ManiSkill's actor builder (boxes, upright
cylinders, spheres, lying capsules); the training objects and the test objects differ in shape
proportions and sizes, so no test object was seen in training. Every episode draws one object of
the split (``envs/variants/pick.py``).

Stage indicators (Appendix A): ``is_grasped`` (both fingers touch the object with non-zero force),
``is_obj_placed`` (within ``placed_thresh`` of the goal, by default ``goal_thresh`` = 2.5 cm:
``+env.variant_overrides.placed_thresh=0.05`` moves the indicator alone) and ``success`` = within
``goal_thresh``, robot static (joint speeds
< 0.2 rad/s) and object static (< 3 cm/s; ``object_static_thresh``).
"""

from drs_torchrl.tasks import TaskFamily, register_family
from drs_torchrl.tasks.pick_cube import PANDA_PICK_OBSERVATION_GROUPS, PICK_TASK_OBSERVATION_GROUPS


def _obj(shape, size):
    return {"object_shape": shape, "object_size": size}


TRAIN_OBJECTS = {
    "cube_2cm": _obj("cube", 0.02),
    "box_tall": _obj("box", [0.02, 0.02, 0.035]),
    "box_flat": _obj("box", [0.03, 0.02, 0.015]),
    "cylinder_r2cm": _obj("cylinder", [0.02, 0.025]),
    "sphere_r2cm": _obj("sphere", 0.02),
    "capsule_r1_5cm": _obj("capsule", [0.015, 0.02]),
}
TEST_OBJECTS = {
    "cube_1_5cm": _obj("cube", 0.015),
    "box_long": _obj("box", [0.035, 0.0125, 0.02]),
    "cylinder_r1_5cm_tall": _obj("cylinder", [0.015, 0.035]),
    "sphere_r1_75cm": _obj("sphere", 0.0175),
    "capsule_r2cm": _obj("capsule", [0.02, 0.01]),
}

register_family(
    TaskFamily(
        name="pick_and_place",
        env_id="PickObject-v1",
        description="Panda picks an object (boxes, cylinders, spheres, capsules) and holds it at a goal (Appendix A)",
        stage_keys=("is_grasped", "is_obj_placed", "success"),
        info_keys=("is_robot_static", "is_obj_static"),
        variants={**TRAIN_OBJECTS, **TEST_OBJECTS},
        train_variants=tuple(TRAIN_OBJECTS),
        test_variants=tuple(TEST_OBJECTS),
        pooled=True,
        extra={
            "demo_solver": "mani_skill.examples.motionplanning.panda.solutions.pick_cube:solve",
            "demo_settle_steps": 20,
            "observation_groups": PANDA_PICK_OBSERVATION_GROUPS,
            "task_observation_groups": PICK_TASK_OBSERVATION_GROUPS,
        },
    )
)
