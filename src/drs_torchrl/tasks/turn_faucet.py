"""``turn_faucet``: Panda turns a faucet handle (ManiSkill TurnFaucet-v1, PartNet-Mobility faucets).

DrS paper, Sec. 5.1 and Appendix A ("Turn Faucet"): rewards learned on 10 faucets and reused on 50
others. ManiSkill ships 60 faucet models; the 10 with the lowest ids are the training faucets and
the other 50 the test faucets; every episode loads one faucet of the split. Needs the assets:
``python -m mani_skill.utils.download_asset partnet_mobility_faucet -y``; without them the env fails
at once with that command.

Stage indicators (Appendix A): ``is_handle_moving`` (the target joint turns towards its goal faster
than 0.01 rad/s, ``moving_thresh``) and ``success`` (the joint beyond 90% of its range, ManiSkill's).
Control: end-effector delta pose and gripper position, as the paper.
"""

from drs_torchrl.tasks import TaskFamily, register_family
from drs_torchrl.tasks._assets import partnet_meta

FAUCETS = sorted(partnet_meta("faucet"), key=int)

register_family(
    TaskFamily(
        name="turn_faucet",
        env_id="TurnFaucetSplit-v1",
        description="Panda turns a faucet handle: 10 training faucets, 50 test faucets (needs the faucet assets)",
        stage_keys=("is_handle_moving", "success"),
        variants={f"faucet_{m}": {"model_ids": [m]} for m in FAUCETS},
        train_variants=tuple(f"faucet_{m}" for m in FAUCETS[:10]),
        test_variants=tuple(f"faucet_{m}" for m in FAUCETS[10:]),
        control_mode="pd_ee_delta_pose",
        max_episode_steps=200,
        pooled=True,
        extra={"assets": "partnet_mobility_faucet"},
    )
)
