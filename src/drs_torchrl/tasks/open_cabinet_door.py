"""``open_cabinet_door``: Fetch opens a designated door of a cabinet (ManiSkill OpenCabinetDoor-v1).

DrS paper, Sec. 5.1 and Appendix A ("Open Cabinet Door"): rewards learned on 4 cabinet doors and
reused on 6, single-door cabinets removed (a kick on the side opens them, which sparse rewards
learn readily). Of ManiSkill's cabinets with two or more doors (its metadata's
``num_target_links``), the 4 with the lowest ids are the training cabinets and the next 6 the test
cabinets; every episode loads one cabinet of the split and one of its doors. Needs the assets:
``python -m mani_skill.utils.download_asset partnet_mobility_cabinet -y``; without them the env
fails at once with that command.

Stage indicators (Appendix A and its listing of the authors' indicators): ``is_handle_grasped``,
``open_enough`` (the door's joint beyond 90% of its range; ManiSkill's own default is 75%) and
``success`` = open enough and the door static (< 0.1 m/s and < 1 rad/s; ``is_door_static``).
Control: joint velocities of the arm and base, gripper position, as the paper.
"""

from drs_torchrl.tasks import TaskFamily, register_family
from drs_torchrl.tasks._assets import partnet_meta

CABINETS = sorted(
    (m for m, info in partnet_meta("cabinet_door").items() if int(info.get("num_target_links", 1)) >= 2), key=int
)

register_family(
    TaskFamily(
        name="open_cabinet_door",
        env_id="OpenCabinetDoorSplit-v1",
        description="Fetch opens a cabinet door: 4 training cabinets, 6 test cabinets (needs the cabinet assets)",
        stage_keys=("is_handle_grasped", "open_enough", "success"),
        info_keys=("is_door_static",),
        variants={f"cabinet_{m}": {"model_ids": [m]} for m in CABINETS},
        train_variants=tuple(f"cabinet_{m}" for m in CABINETS[:4]),
        test_variants=tuple(f"cabinet_{m}" for m in CABINETS[4:10]),
        control_mode="pd_joint_vel",
        max_episode_steps=100,
        pooled=True,
        extra={"assets": "partnet_mobility_cabinet"},
    )
)
