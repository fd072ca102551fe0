"""``turn_valve``: a D'Claw hand turns a ROBEL valve; ManiSkill's RotateValve levels are the variants.

The five levels (``RotateValveLevel0..4-v1`` in ManiSkill, one scene here: ``envs/variants/valve.py``)
differ in valve geometry (spoke count, angles, length, thickness), goal angle (pi/2, pi, pi, pi,
2 pi) and, at level 4, turning direction. The reward is learned on levels 0, 2 and 4 and reused on
levels 1 and 3 (fixed 3/4/5-spoke valves; random spokes of random size). Every episode draws a
level of the split and one of its valves.

Stage indicators, after Appendix A's Turn Faucet ("the handle is moving", "the handle reached the
target angle"): ``is_valve_turning`` (the valve turned by more than ``turning_thresh`` = 0.01 rad,
i.e. 0.2 rad/s at the 20 Hz control rate, in the commanded direction during the last control step;
``+env.variant_overrides.turning_thresh=...``) and ``success`` (ManiSkill's goal rotation reached).
Episode lengths are ManiSkill's per level (80, 150, 150, 150, 300 steps: ``LEVEL_STEPS`` in
``envs/variants/valve.py``); ``+env.variant_overrides.max_steps=150`` gives every level one limit.
The episode's stage is the highest it reached (the stage buffers file it there), so a valve that
stops turning does not undo the episode's progress.
"""

from drs_torchrl.tasks import TaskFamily, register_family

register_family(
    TaskFamily(
        name="turn_valve",
        env_id="RotateValveVariants-v1",
        description="D'Claw turns a valve; ManiSkill RotateValve levels 0-4 as variants",
        stage_keys=("is_valve_turning", "success"),
        variants={f"level{k}": {"level": k} for k in range(5)},
        train_variants=("level0", "level2", "level4"),
        test_variants=("level1", "level3"),
        control_mode="pd_joint_delta_pos",
        max_episode_steps=300,  # the longest level's; each episode ends at its own level's (80-300)
        pooled=True,
    )
)
