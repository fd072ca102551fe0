"""``place_sphere``: Panda places a sphere into a shallow bin; the sphere's radius varies.

ManiSkill's PlaceSphere-v1 with the radius as a variant parameter (``envs/variants/place_sphere.py``).
Three stages from PlaceSphere's own ``evaluate``: ``is_obj_grasped``, ``is_obj_on_bin``, and
``success`` (in the bin, static, released). Training radii 2 and 1.5 cm, test radii 1.75 and
1.25 cm, drawn per episode.
"""

from drs_torchrl.tasks import TaskFamily, register_family

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
        extra={"demo_solver": "mani_skill.examples.motionplanning.panda.solutions.place_sphere:solve"},
    )
)
