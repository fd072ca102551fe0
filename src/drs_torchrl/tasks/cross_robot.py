"""``cross_robot``: learn the pick-and-place reward with one robot and reuse it with another.

DrS (Sec. 1, 5) reuses a learned reward on new tasks of a family; here the new task is a new arm.
The reward must then not read the robot's joints: it reads ``task_observation`` (object pose, goal
position, TCP position, TCP-to-object and object-to-goal vectors, positions relative to the centre
of the robot's object spawn region; ``PickObjectEnv.task_observation``) and the stage indicators.
The policy still sees the robot's full state.

Robots that ManiSkill 3.0.1 ships without downloads: Panda (training, end-effector delta position
control), Fetch (test, the same controller on its arm; body and base actions too) and SO100
(``env.split=so100_cube_1_25cm``: joint delta control, a 1.25 cm cube in ManiSkill's SO100 PickCube
workspace; not in the test split because its action and observation sizes differ from Fetch's, and
one split's variants must share them). Each robot works in ManiSkill's PickCube workspace for it.
Stage indicators as ``pick_and_place`` (Appendix A).
"""

from drs_torchrl.tasks import TaskFamily, register_family


def _v(robot, size, **kw):
    return {"robot_uids": robot, "object_shape": "cube", "object_size": size, **kw}


register_family(
    TaskFamily(
        name="cross_robot",
        env_id="PickObject-v1",
        description="pick-and-place reward learned with Panda, reused with Fetch (robot-agnostic reward inputs)",
        stage_keys=("is_grasped", "is_obj_placed", "success"),
        info_keys=("is_robot_static", "is_obj_static"),
        reward_in_keys=("task_observation", "stage_indicators"),
        task_observation_key="task_observation",
        variants={
            "panda_cube_2cm": _v("panda", 0.02),
            "panda_cube_1_75cm": _v("panda", 0.0175),
            "fetch_cube_2cm": _v("fetch", 0.02),
            "fetch_cube_1_75cm": _v("fetch", 0.0175),
            "so100_cube_1_25cm": _v("so100", 0.0125, control_mode="pd_joint_delta_pos"),
        },
        train_variants=("panda_cube_2cm", "panda_cube_1_75cm"),
        test_variants=("fetch_cube_2cm", "fetch_cube_1_75cm"),
        pooled=True,
        # ManiSkill's motion planner drives the Panda: demonstrations for the training split
        extra={
            "demo_solver": "mani_skill.examples.motionplanning.panda.solutions.pick_cube:solve",
            "demo_settle_steps": 20,
        },
    )
)
