"""The ManiSkill3 -> TorchRL env on the real simulator (SAPIEN, software Vulkan on CPU)."""

import pytest
import torch
from torchrl.envs.utils import check_env_specs

from drs_torchrl.envs import ManiSkillEnv, make_family_env
from drs_torchrl.transforms import DrSReward


@pytest.fixture(scope="module")
def env(pick_cube):
    e = make_family_env(pick_cube, "train", seed=0)
    yield e
    e.close()


@pytest.mark.sim
def test_specs_pass_and_indicators_reach_the_tensordict(env, pick_cube):
    check_env_specs(env)
    td = env.rollout(5)
    for k in (*pick_cube.stage_keys, "stage", "stage_indicators"):
        assert ("next", k) in td.keys(True)
    assert td["next", "observation"].shape == (5, 42)
    assert td["action"].shape == (5, 4)
    assert td["next", "stage"].dtype == torch.int64


@pytest.mark.sim
def test_specs_pass_with_the_learned_reward_and_semi_sparse_reward(pick_cube):
    e = make_family_env(pick_cube, "test", semi_sparse_reward=True, seed=1)
    try:
        check_env_specs(e)
        td = e.rollout(3)
        assert torch.equal(td["next", "reward"], td["next", "stage"].float() - 3)
        r = DrSReward.from_spec(e.observation_spec, 3, ["observation", "stage_indicators"])
        e.append_transform(r)
        check_env_specs(e)
        td = e.rollout(3)
        assert torch.allclose(td["next", "reward"], r.reward(td["next"]))
    finally:
        e.close()


@pytest.mark.sim
def test_variants_change_the_object(pick_cube):
    small = make_family_env(pick_cube, "cube_1_5cm", seed=0)
    over = make_family_env(pick_cube, "train", variant_overrides={"cube_half_size": 0.03}, seed=0)
    try:
        assert small.base_env.unwrapped.cube_half_size == pytest.approx(0.015)
        assert over.base_env.unwrapped.cube_half_size == pytest.approx(0.03)
        # the cube rests on the table: its centre is at its half size, in the simulator
        for e, h in ((small, 0.015), (over, 0.03)):
            e.reset()
            assert float(e.base_env.unwrapped.cube.pose.p[0, 2]) == pytest.approx(h, abs=2e-3)
    finally:
        small.close()
        over.close()


@pytest.mark.sim
def test_same_seed_same_first_observation(pick_cube):
    a = make_family_env(pick_cube, "train", seed=7)
    b = make_family_env(pick_cube, "train", seed=7)
    try:
        assert torch.equal(a.reset()["observation"], b.reset()["observation"])
    finally:
        a.close()
        b.close()


@pytest.mark.sim
def test_unknown_indicator_key_is_reported():
    with pytest.raises(KeyError, match="is_lifted"):
        ManiSkillEnv("PickCube-v1", ["is_lifted"])


def test_gpu_backend_without_cuda_is_reported(monkeypatch):
    """On any machine: CUDA made unavailable, the GPU backend is refused before anything is imported or built."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(RuntimeError, match="sim_backend='physx_cuda' was requested but CUDA is not available"):
        ManiSkillEnv("PickCube-v1", ["success"], sim_backend="physx_cuda", num_envs=4)
    with pytest.raises(RuntimeError, match="CUDA is not available"):
        ManiSkillEnv("PickCube-v1", ["success"], sim_backend="cuda", num_envs=4)
    with pytest.raises(ValueError, match="SerialEnv"):  # auto without CUDA: the CPU backend, one env per process
        ManiSkillEnv("PickCube-v1", ["success"], sim_backend="auto", num_envs=4)


@pytest.mark.sim
@pytest.mark.skipif(not torch.cuda.is_available(), reason="the GPU simulation needs CUDA (its refusal: the test above)")
def test_gpu_backend_steps_batched_envs_on_cuda():
    """Where CUDA is: physx_cuda runs num_envs scenes in one env on the GPU (``auto`` picks it for num_envs > 1)."""
    e = ManiSkillEnv("PickCube-v1", ["success"], sim_backend="auto", num_envs=4)
    try:
        assert e.gpu and e.batch_size == (4,) and e.device.type == "cuda"
        td = e.rollout(3)
        assert td["next", "observation"].shape[:2] == (4, 3) and td["next", "observation"].device.type == "cuda"
        assert ("next", "success") in td.keys(True)
    finally:
        e.close()


def test_several_cpu_envs_need_batched_envs():
    with pytest.raises(ValueError, match="SerialEnv"):
        ManiSkillEnv("PickCube-v1", ["success"], num_envs=2)


@pytest.mark.sim
def test_missing_asset_fails_fast_with_download_command():
    from drs_torchrl.envs import MissingAssetError
    from drs_torchrl.envs.doctor import missing_assets

    if not missing_assets("PickSingleYCB-v1"):
        pytest.skip("the YCB assets are downloaded on this machine")
    with pytest.raises(MissingAssetError, match="mani_skill.utils.download_asset PickSingleYCB-v1"):
        ManiSkillEnv("PickSingleYCB-v1", ["success"])


@pytest.mark.sim
def test_several_cpu_envs_through_torchrl_batched_env(pick_cube):
    e = make_family_env(pick_cube, "train", num_envs=2, seed=3)
    try:
        assert e.batch_size == (2,)
        check_env_specs(e)
        td = e.rollout(4)
        assert td["next", "stage"].shape == (2, 4, 1)
        assert not torch.equal(td["next", "observation"][0], td["next", "observation"][1])
    finally:
        e.close()
