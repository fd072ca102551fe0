"""Task families on the real simulator: every family this machine can run, and the asset-backed ones' errors.

For each runnable family: the train and test splits build, pass TorchRL's spec check, step, carry
stage labels; the splits are disjoint; every episode draws a variant of the split and the scene
really changes with it; a variant override from the Hydra config reaches the simulator. The
asset-backed families (YCB, PartNet-Mobility) fail at once with the download command.
"""

import time
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf
from torchrl.envs.utils import check_env_specs

from drs_torchrl.envs import MissingAssetError, make_family_env
from drs_torchrl.envs.doctor import missing_assets
from drs_torchrl.tasks import get_family, list_families


CONF = Path(__file__).resolve().parents[1] / "conf"
RUNNABLE = ["pick_cube", "pick_and_place", "turn_valve", "stack_cube", "place_sphere", "cross_robot"]
ASSET_BACKED = {
    "pick_ycb": "ycb",
    "turn_faucet": "partnet_mobility_faucet",
    "open_cabinet_door": "partnet_mobility_cabinet",
}
# (variant parameter, value) overridden from the command line in the config test
OVERRIDE = {
    "pick_cube": ("cube_half_size", 0.03),
    "pick_and_place": ("goal_thresh", 0.05),
    "turn_valve": ("turning_thresh", 0.05),
    "stack_cube": ("cube_b_half_size", 0.03),
    "place_sphere": ("sphere_radius", 0.011),
    "cross_robot": ("goal_thresh", 0.05),
}


def _object_height(u) -> float | None:
    """Height above the table of the episode's object (None for the valve)."""
    for name in ("cubeA", "obj", "cube"):
        if hasattr(type(u), name):
            return float(getattr(u, name).pose.p[0, 2])
    return None


def _expected_height(family, variant: dict) -> float | None:
    from drs_torchrl.envs.variants.pool import ObjectSpec

    if family.name == "pick_cube":
        return variant["cube_half_size"]
    if family.name in ("pick_and_place", "cross_robot"):
        return ObjectSpec.make(variant["object_shape"], variant["object_size"]).rest_height
    if family.name == "stack_cube":
        return variant["cube_a_half_size"]
    if family.name == "place_sphere":
        return variant["sphere_radius"]
    return None


@pytest.fixture(scope="module", params=RUNNABLE)
def family_envs(request):
    fam = get_family(request.param)
    envs = {split: make_family_env(fam, split, seed=3) for split in ("train", "test")}
    yield fam, envs
    for e in envs.values():
        e.close()


@pytest.mark.sim
def test_splits_build_step_and_label_stages(family_envs):
    fam, envs = family_envs
    assert set(fam.train_variants).isdisjoint(fam.test_variants) and fam.train_variants and fam.test_variants
    for split, env in envs.items():
        check_env_specs(env)
        td = env.rand_step(env.reset())
        td = env.rollout(4, break_when_any_done=False)
        for k in (*fam.stage_keys, "stage", "stage_indicators", "variant_index"):
            assert ("next", k) in td.keys(True), (fam.name, split, k)
        assert td["next", "stage_indicators"].shape[-1] == fam.num_stages
        assert 0 <= int(td["next", "stage"].min()) and int(td["next", "stage"].max()) <= fam.num_stages
        for k in fam.reward_in_keys:
            assert k in env.observation_spec.keys(True), (fam.name, k)
    # train and test share the observation and action layout (what reward reuse needs) unless the robot changes
    if fam.name != "cross_robot":
        assert envs["train"].observation_spec["observation"].shape == envs["test"].observation_spec["observation"].shape


@pytest.mark.sim
@pytest.mark.parametrize("name", [n for n in RUNNABLE if get_family(n).extra.get("observation_groups")])
def test_named_observation_columns_hold_what_their_names_say(name):
    """A family's ``observation_groups`` (what ``drs-probe --swap-with`` reports) tile the observation and
    the joint-velocity and TCP-pose columns read back the simulator's values."""
    fam = get_family(name)
    layout = fam.extra["observation_groups"]
    env = make_family_env(fam, "test", seed=0)
    try:
        ranges = sorted(layout.values())
        assert ranges[0][0] == 0 and all(a[1] == b[0] for a, b in zip(ranges, ranges[1:]))
        assert ranges[-1][1] == env.observation_spec["observation"].shape[-1]
        td = env.rand_step(env.reset())
        obs, u = td["next", "observation"].reshape(-1), env.base_env.unwrapped
        s, e = layout["joint velocities"]
        torch.testing.assert_close(obs[s:e], u.agent.robot.get_qvel().reshape(-1).to(obs.dtype))
        s, e = layout["TCP pose"]
        torch.testing.assert_close(obs[s:e], u.agent.tcp.pose.raw_pose.reshape(-1).to(obs.dtype))
    finally:
        env.close()


@pytest.mark.sim
def test_every_episode_draws_a_variant_of_the_split(family_envs):
    fam, envs = family_envs
    for split, env in envs.items():
        names = fam.split_variants(split)
        base = env.base_env
        assert base.variant_names == list(names)
        seen = []
        for _ in range(16):
            td = env.reset()
            idx = int(td["variant_index"])
            seen.append(idx)
            u = base.unwrapped
            assert u.current_variant == names[idx]
            want = _expected_height(fam, fam.variants[names[idx]])
            if want is not None:  # the scene has the variant's object on the table
                assert _object_height(u) == pytest.approx(want, abs=2e-3), (fam.name, names[idx])
            if fam.name == "turn_valve":
                level = fam.variants[names[idx]]["level"]
                assert u._valve_level[u._active_valve] == level
                assert float(u.success_threshold[0]) == pytest.approx(
                    {0: 1.5708, 4: 6.2832}.get(level, 3.1416), abs=1e-3
                )
        assert len(set(seen)) >= 2, f"{fam.name}/{split}: 16 resets drew only {set(seen)}"


@pytest.mark.sim
def test_a_variant_override_from_the_config_reaches_the_simulator(family_envs):
    fam, _ = family_envs
    key, value = OVERRIDE[fam.name]
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        cfg = compose("learn", overrides=[f"env={fam.name}", f"+env.variant_overrides.{key}={value}", "env.split=test"])
    assert cfg.env.family == fam.name
    env = make_family_env(
        fam, cfg.env.split, variant_overrides=OmegaConf.to_container(cfg.env.variant_overrides), seed=0
    )
    try:
        u = env.base_env.unwrapped
        for _ in range(3):
            env.reset()
            assert float(u._param(key)[0]) == pytest.approx(value)
        if key in ("cube_half_size", "sphere_radius"):
            assert _object_height(u) == pytest.approx(value, abs=2e-3)
        if key == "cube_b_half_size":
            assert float(u.cubeB.pose.p[0, 2]) == pytest.approx(value, abs=2e-3)
    finally:
        env.close()


@pytest.mark.sim
def test_one_named_variant_stays_fixed():
    fam = get_family("pick_and_place")
    env = make_family_env(fam, "sphere_r2cm", seed=0)
    try:
        for _ in range(4):
            env.reset()
            assert env.base_env.unwrapped.current_variant == "sphere_r2cm"
            assert _object_height(env.base_env.unwrapped) == pytest.approx(0.02, abs=2e-3)
    finally:
        env.close()


@pytest.mark.sim
@pytest.mark.slow
def test_turn_valve_episodes_end_at_their_own_levels_time_limit():
    """ManiSkill's RotateValve levels have their own time limits (80 / 150 / 300); a pooled env keeps them."""
    from drs_torchrl.envs.variants.valve import LEVEL_STEPS

    fam = get_family("turn_valve")

    def hold_still(tensordict):  # no motion: the valve cannot reach its goal, so only the time limit ends an episode
        return tensordict.set("action", torch.zeros(9))

    # the train split draws levels 0, 2, 4 per episode: each episode ends at its own level's limit
    env = make_family_env(fam, "train", seed=3)
    try:
        names, levels = env.base_env.variant_names, set()
        for _ in range(6):
            td = env.rollout(400, policy=hold_still, break_when_any_done=True)
            level = fam.variants[names[int(td["variant_index"][0])]]["level"]
            levels.add(level)
            assert td.shape[0] == LEVEL_STEPS[level], level
            assert bool(td["next", "truncated"][-1]) and not bool(td["next", "truncated"][:-1].any())
            assert not bool(td["next", "terminated"].any())
        assert len(levels) >= 2, levels
    finally:
        env.close()
    # a variant parameter sets one length (longer than the family's 300 too); env.max_episode_steps caps it
    for variant, overrides, cap, steps in (
        ("level4", {"max_steps": 7}, None, 7),
        ("level1", {"max_steps": 320}, None, 320),
        ("level0", None, 50, 50),
    ):
        env = make_family_env(fam, variant, variant_overrides=overrides, max_episode_steps=cap, seed=0)
        try:
            assert env.rollout(400, policy=hold_still, break_when_any_done=True).shape[0] == steps, (
                variant,
                overrides,
                cap,
            )
        finally:
            env.close()
    with pytest.raises(ValueError, match="max_steps"):
        make_family_env(fam, "level1", variant_overrides={"max_steps": 0}, seed=0)


@pytest.mark.sim
def test_cross_robot_reward_reads_robot_agnostic_entries_and_fits_every_robot():
    from hydra.utils import instantiate

    from drs_torchrl.transforms import DrSReward

    fam = get_family("cross_robot")
    assert "task_observation" in fam.reward_in_keys and "observation" not in fam.reward_in_keys
    envs = [make_family_env(fam, split, seed=0) for split in ("train", "so100_cube_1_25cm")]
    try:
        panda, so100 = envs
        assert panda.observation_spec["observation"].shape != so100.observation_spec["observation"].shape
        assert panda.action_spec.shape != so100.action_spec.shape
        reward_cfg = OmegaConf.load(CONF / "reward" / "drs.yaml")  # its model builder, as a drs-learn run calls it
        reward = instantiate(reward_cfg.model)(panda, fam.num_stages, list(fam.reward_in_keys), metadata={})
        reward.check_compatible(so100.observation_spec, num_stages=fam.num_stages, family=fam.name)
        td = so100.rollout(3)
        assert td["next", "task_observation"].shape == (3, 19)
        assert reward.reward(td["next"]).shape == (3, 1)
        # the TCP-to-object vector is what the simulator says, in the robot-independent frame
        u = so100.base_env.unwrapped
        t = u.task_observation()[0]
        assert torch.allclose(t[13:16], u.obj.pose.p[0] - u.agent.tcp_pose.p[0], atol=1e-5)
        assert isinstance(DrSReward.from_spec(panda.observation_spec, 3, list(fam.reward_in_keys)), DrSReward)
    finally:
        for e in envs:
            e.close()


@pytest.mark.sim
@pytest.mark.parametrize("name", ["pick_cube", "pick_and_place"])
def test_env_task_observation_adds_the_task_state_to_the_pick_envs(name):
    """env.task_observation=true: the env also writes the 19-number task state (spec-checked); off by default."""
    from drs_torchrl.tasks import family_from_config

    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        off = family_from_config(compose("learn", overrides=[f"env={name}"]).env)
        on = family_from_config(compose("learn", overrides=[f"env={name}", "env.task_observation=true"]).env)
    assert off.task_observation_key is None and on.task_observation_key == "task_observation"
    from drs_torchrl.tasks import with_task_observation

    with pytest.raises(
        ValueError, match="family 'turn_valve' has no task state; the families that have one: .*'pick_cube'"
    ):
        with_task_observation(get_family("turn_valve"), True)
    env = make_family_env(on, "test", seed=0)
    try:
        check_env_specs(env)
        td = env.rollout(3)
        obs, task = td["next", "observation"], td["next", "task_observation"]
        assert task.shape == (3, 19)
        # the task state's object-to-goal vector is the observation's (ManiSkill's obj_to_goal_pos, its last 3 numbers)
        assert torch.allclose(task[:, 16:19], obs[:, 39:42], atol=1e-5)
    finally:
        env.close()


def test_every_family_has_a_config_and_asset_families_are_registered():
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        for name in list_families():
            assert compose("learn", overrides=[f"env={name}"]).env.family == name
        # a family may set its own SAC defaults (HalfCheetah's 1000-step episodes: gamma 0.99); the command line wins
        assert compose("learn", overrides=["env=pick_cube"]).algo.gamma == pytest.approx(0.8)
        assert compose("reuse", overrides=["env=half_cheetah"]).algo.gamma == pytest.approx(0.99)
        assert compose("learn", overrides=["env=half_cheetah", "algo.gamma=0.9"]).algo.gamma == pytest.approx(0.9)
    assert set(RUNNABLE) | set(ASSET_BACKED) <= set(list_families())
    faucet, cabinet = get_family("turn_faucet"), get_family("open_cabinet_door")
    assert (len(faucet.train_variants), len(faucet.test_variants)) == (10, 50)  # the paper's split
    assert (len(cabinet.train_variants), len(cabinet.test_variants)) == (4, 6)


@pytest.mark.sim
@pytest.mark.parametrize("name", sorted(ASSET_BACKED))
def test_asset_backed_families_fail_at_once_with_the_download_command(name):
    fam = get_family(name)
    args = fam.env_args("train")
    if not missing_assets(args["env_id"], args["env_kwargs"]):
        pytest.skip(f"the {ASSET_BACKED[name]} assets are downloaded on this machine")
    for split in ("train", "test"):
        t0 = time.time()
        with pytest.raises(MissingAssetError) as e:
            make_family_env(fam, split)
        assert time.time() - t0 < 10
        assert f"python -m mani_skill.utils.download_asset {ASSET_BACKED[name]} -y" in str(e.value)


@pytest.mark.sim
@pytest.mark.slow
@pytest.mark.parametrize("name", ["pick_and_place", "stack_cube", "place_sphere", "cross_robot"])
def test_motion_planner_demos_for_the_new_families(name):
    from drs_torchrl.demos import check_demos, record_demos

    fam = get_family(name)
    states, meta = record_demos(fam, "train", 1, seed=0, progress=False)
    assert bool(states["success"][-1]) and int(states["stage"][-1]) == fam.num_stages
    assert meta["env_id"] == fam.env_id and meta["variant_kwargs"]["variant_names"] == list(fam.train_variants)
    shapes = {
        "observation": 48 if name == "stack_cube" else 39 if name == "place_sphere" else 42,
        "stage_indicators": 3,
    }
    if fam.task_observation_key:
        shapes[fam.task_observation_key] = 19
        assert states[fam.task_observation_key].shape == (states.shape[0], 19)
    check_demos(meta, fam, {k: shapes[k] for k in fam.reward_in_keys})
