"""``half_cheetah``: MuJoCo HalfCheetah with one stage, success = episode return above 4800.

DrS paper, Appendix G ("Locomotion"): the one-stage version of DrS learns a reusable reward for
Gymnasium's HalfCheetah. Success is "the accumulated dense reward exceeds 4800" (Gymnasium's
``reward_threshold`` of the task); the indicator ``success`` is the running episode return having
passed that threshold (latched for the rest of the episode). Reward learning uses the standard
task; reward reuse the same task with the damping of the front leg's joints (``fthigh``,
``fshin``, ``ffoot``) multiplied by 1.5, which makes high speeds harder.

The paper used ``HalfCheetah-v3`` (mujoco-py, no longer installable); this family uses ``-v5``, the
same model and reward on the maintained ``mujoco`` bindings. Episodes last 1000 steps and do not
end on success. The threshold is a variant parameter:
``+env.variant_overrides.success_return=100`` (or ``env.variant_overrides.success_return=...``
with ``env=half_cheetah``, whose config lists it).
"""

from drs_torchrl.tasks import TaskFamily, register_family

FRONT_LEG_JOINTS = ("fthigh", "fshin", "ffoot")

register_family(
    TaskFamily(
        name="half_cheetah",
        env_id="HalfCheetah-v5",
        backend="gymnasium",
        description="MuJoCo HalfCheetah; success = episode return > 4800 (one stage, Appendix G)",
        stage_keys=("success",),
        variants={
            "standard": {},
            "front_damping_1_5x": {"joint_damping_scale": {j: 1.5 for j in FRONT_LEG_JOINTS}},
        },
        train_variants=("standard",),
        test_variants=("front_damping_1_5x",),
        control_mode=None,  # torque control; Gymnasium envs have no controller choice
        max_episode_steps=1000,
        extra={"success_return": 4800.0},
    )
)
