"""``stack_cube``: Panda stacks a red cube on a green one; the cube sizes vary.

ManiSkill's StackCube-v1 with both half sizes as variant parameters (``envs/variants/stack_cube.py``).
Three stages from StackCube's own ``evaluate``: ``is_cubeA_grasped``, ``is_cubeA_on_cubeB``, and
``success`` (on top, static, released). Training pairs (A, B): 2/2 cm and 1.75/2.5 cm; test pairs
2.25/2.25 cm and 1.5/2.25 cm (half sizes), drawn per episode.
"""

from drs_torchrl.tasks import PANDA_STATE, TaskFamily, column_groups, register_family

# column ranges of StackCube's state observation with the Panda (48 numbers): qpos, qvel, then the task's
# extras in ManiSkill's order; names the inputs in ``drs-probe --swap-with`` (checked in tests/test_families.py)
STACK_OBSERVATION_GROUPS = column_groups(
    *PANDA_STATE,
    ("TCP pose", 7),
    ("cube A pose", 7),
    ("cube B pose", 7),
    ("TCP to cube A", 3),
    ("TCP to cube B", 3),
    ("cube A to cube B", 3),
)


def _pair(a, b):
    return {"cube_a_half_size": a, "cube_b_half_size": b}


register_family(
    TaskFamily(
        name="stack_cube",
        env_id="StackCubeSized-v1",
        description="Panda stacks cube A on cube B; cube sizes vary",
        stage_keys=("is_cubeA_grasped", "is_cubeA_on_cubeB", "success"),
        info_keys=("is_cubeA_static",),
        variants={
            "a2cm_b2cm": _pair(0.02, 0.02),
            "a1_75cm_b2_5cm": _pair(0.0175, 0.025),
            "a2_25cm_b2_25cm": _pair(0.0225, 0.0225),
            "a1_5cm_b2_25cm": _pair(0.015, 0.0225),
        },
        train_variants=("a2cm_b2cm", "a1_75cm_b2_5cm"),
        test_variants=("a2_25cm_b2_25cm", "a1_5cm_b2_25cm"),
        pooled=True,
        extra={
            "demo_solver": "mani_skill.examples.motionplanning.panda.solutions.stack_cube:solve",
            "observation_groups": STACK_OBSERVATION_GROUPS,
        },
    )
)
