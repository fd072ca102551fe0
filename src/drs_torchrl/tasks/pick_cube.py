"""``pick_cube``: Panda picks a cube of one of four sizes and holds it at a goal (Appendix A).

``env.split=train`` draws the cube size of every episode from the training sizes (2 and 2.5 cm),
``env.split=test`` from the held-out ones (1.5 and 1.75 cm); a variant name fixes one size.
"""

from drs_torchrl.tasks import PANDA_STATE, TaskFamily, column_groups, register_family

# column ranges of ManiSkill's PickCube state observation with the Panda (42 numbers): the agent's qpos and
# qvel, then the task's extras in ManiSkill's order
PANDA_PICK_OBSERVATION_GROUPS = column_groups(
    *PANDA_STATE,
    ("is_grasped", 1),
    ("TCP pose", 7),
    ("goal position", 3),
    ("object pose", 7),
    ("TCP to object", 3),
    ("object to goal", 3),
)
# and of PickObjectEnv.task_observation() (19 numbers, positions in the workspace frame)
PICK_TASK_OBSERVATION_GROUPS = column_groups(
    ("object position", 3),
    ("object orientation", 4),
    ("goal position", 3),
    ("TCP position", 3),
    ("TCP to object", 3),
    ("object to goal", 3),
)

register_family(
    TaskFamily(
        name="pick_cube",
        env_id="PickCubeSized-v1",
        description="Panda picks a cube and holds it at a goal in mid-air (Pick-and-Place, Appendix A)",
        # grasped -> placed (within placed_thresh, by default goal_thresh) -> within goal_thresh and static (= success)
        stage_keys=("is_grasped", "is_obj_placed", "success"),
        info_keys=("is_robot_static",),
        variants={
            "cube_2cm": {"cube_half_size": 0.02},
            "cube_1_5cm": {"cube_half_size": 0.015},
            "cube_2_5cm": {"cube_half_size": 0.025},
            "cube_1_75cm": {"cube_half_size": 0.0175},
        },
        train_variants=("cube_2cm", "cube_2_5cm"),
        test_variants=("cube_1_5cm", "cube_1_75cm"),
        pooled=True,
        extra={
            "demo_solver": "mani_skill.examples.motionplanning.panda.solutions.pick_cube:solve",
            "observation_groups": PANDA_PICK_OBSERVATION_GROUPS,
            "task_observation_groups": PICK_TASK_OBSERVATION_GROUPS,
        },
    )
)
