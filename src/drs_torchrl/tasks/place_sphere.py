"""``place_sphere``: Panda places a sphere into a shallow bin; the sphere's radius varies.

ManiSkill's PlaceSphere-v1 with the radius as a variant parameter (``envs/variants/place_sphere.py``).
Three stages from PlaceSphere's own ``evaluate``: ``is_obj_grasped``, ``is_obj_on_bin``, and
``success`` (in the bin, static, released). Training radii 2 and 1.5 cm, test radii 1.75 and
1.25 cm, drawn per episode.
"""

from drs_torchrl.tasks import PANDA_STATE, TaskFamily, column_groups, register_family

# column ranges of PlaceSphere's state observation with the Panda (39 numbers): qpos, qvel, then the task's
# extras in ManiSkill's order; names the inputs in ``drs-probe --swap-with`` (checked in tests/test_families.py)
PLACE_SPHERE_OBSERVATION_GROUPS = column_groups(
    *PANDA_STATE,
    ("is_grasped", 1),
    ("TCP pose", 7),
    ("bin position", 3),
    ("sphere pose", 7),
    ("TCP to sphere", 3),
)

register_family(
    TaskFamily(
        name="place_sphere",
        env_id="PlaceSphereSized-v1",
        description="Panda places a sphere in a bin; the radius varies",
        stage_keys=("is_obj_grasped", "is_obj_on_bin", "success"),
        info_keys=("is_obj_static",),
        variants={
            "r2cm": {"sphere_radius": 0.02},
            "r1_5cm": {"sphere_radius": 0.015},
            "r1_75cm": {"sphere_radius": 0.0175},
            "r1_25cm": {"sphere_radius": 0.0125},
        },
        train_variants=("r2cm", "r1_5cm"),
        test_variants=("r1_75cm", "r1_25cm"),
        pooled=True,
        extra={
            "demo_solver": "mani_skill.examples.motionplanning.panda.solutions.place_sphere:solve",
            "observation_groups": PLACE_SPHERE_OBSERVATION_GROUPS,
        },
    )
)
