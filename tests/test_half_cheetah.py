"""The ``half_cheetah`` family (DrS paper, Appendix G): MuJoCo HalfCheetah through TorchRL's GymWrapper,
one stage (success = running episode return above a threshold), front-leg damping x1.5 at test time."""

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from torchrl.envs.utils import check_env_specs

pytest.importorskip("mujoco", reason="the locomotion extra (pip install -e '.[locomotion]') is not installed")

from drs_torchrl.envs.factory import make_family_env
from drs_torchrl.envs.gym_family import GymFamilyError
from drs_torchrl.tasks import get_family
from drs_torchrl.transforms import DrSReward
from budgets import HALF_CHEETAH, tiny

torch.set_num_threads(1)
BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def family():
    return get_family("half_cheetah")


def _gym(env):
    """The Gymnasium env under a TransformedEnv(GymWrapper(...))."""
    return env.base_env._env


@pytest.mark.sim
def test_family_envs_have_valid_specs_and_1000_step_episodes(family):
    assert family.backend == "gymnasium" and family.stage_keys == ("success",)
    for split in ("train", "test"):
        env = make_family_env(family, split, reward_mode="dense", seed=0)
        try:
            check_env_specs(env)
            spec = env.observation_spec
            assert spec["observation"].shape == (17,) and spec["observation"].dtype == torch.float32
            assert spec["success"].dtype == torch.bool and spec["success"].shape == (1,)
            assert spec["stage_indicators"].shape == (1,)
            assert env.action_spec.shape == (6,)
            td = env.rollout(1200, break_when_any_done=True)
            assert td.shape == (1000,)
            assert bool(td["next", "truncated"][-1]) and not bool(td["next", "done"][:-1].any())
        finally:
            env.close()


@pytest.mark.sim
def test_test_split_multiplies_front_leg_damping_by_1_5(family):
    import mujoco

    envs = {s: make_family_env(family, s) for s in ("train", "test")}
    try:
        model = _gym(envs["test"]).unwrapped.model
        train = np.asarray(_gym(envs["train"]).unwrapped.model.dof_damping)
        test = np.asarray(model.dof_damping)
        for j in range(model.njnt):
            name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j)
            d = int(model.jnt_dofadr[j])
            factor = 1.5 if name in ("fthigh", "fshin", "ffoot") else 1.0
            assert test[d] == pytest.approx(train[d] * factor), name
        assert (test != train).sum() == 3 and train[[6, 7, 8]].tolist() == [4.5, 3.0, 1.5]
    finally:
        for e in envs.values():
            e.close()
    with pytest.raises(GymFamilyError, match="unknown joints"):
        make_family_env(family, "train", variant_overrides={"joint_damping_scale": {"fleg": 2.0}})
    with pytest.raises(GymFamilyError, match="control_mode"):
        make_family_env(family, "train", control_mode="pd_ee_delta_pos")


@pytest.mark.sim
def test_success_latches_when_the_running_return_passes_the_configured_threshold(family):
    env = make_family_env(
        family, "train", variant_overrides={"success_return": 1.0}, reward_mode="dense", max_episode_steps=100, seed=0
    )
    sparse = make_family_env(
        family, "train", variant_overrides={"success_return": 1.0}, reward_mode="sparse", max_episode_steps=100, seed=0
    )
    flips = 0
    try:
        torch.manual_seed(0)
        for _ in range(8):
            td = env.rollout(100)
            ret = td["next", "reward"].reshape(-1).cumsum(0)
            want = (ret > 1.0).cummax(0).values
            got = td["next", "success"].reshape(-1)
            assert torch.equal(got, want)
            assert torch.equal(td["next", "stage"].reshape(-1), got.long())
            assert not bool(td["success"][0])  # the reset state is not successful
            flips += int(got.any() and not got[0])
        assert flips >= 1
        td = sparse.rollout(100)
        assert torch.equal(td["next", "reward"].reshape(-1), td["next", "success"].reshape(-1).float())
    finally:
        env.close()
        sparse.close()


def _run(cmd, *args, cwd):
    env = dict(os.environ, PYTHONWARNINGS="ignore", OMP_NUM_THREADS="1")
    return subprocess.run(
        [str(BIN / cmd), *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=600, check=False
    )


TINY = [*HALF_CHEETAH, *tiny(frames=384, hidden=32)]


@pytest.mark.sim
@pytest.mark.slow
def test_drs_learn_and_reuse_run_on_half_cheetah(tmp_path):
    learn, reuse = tmp_path / "learn", tmp_path / "reuse"
    p = _run("drs-learn", *TINY, f"hydra.run.dir={learn}", "seed=1", cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    summary = json.loads((learn / "summary.json").read_text())
    assert summary["frames"] >= 384 and summary["updates"] > 0
    eps = summary["stage_buffer_episodes"]
    assert sum(eps) >= 3  # 100-step episodes, filed into stage 0 (failed) or 1 (return passed 1.0)
    assert (summary["disc_updates"] > 0) == (eps[0] > 0 and eps[1] > 0), eps
    reward = DrSReward.from_checkpoint(learn / "checkpoints" / "reward.pt")
    assert reward.metadata["family"] == "half_cheetah" and reward.num_stages == 1
    assert reward.in_shapes == {"observation": 17, "stage_indicators": 1}
    rows = list(csv.DictReader((learn / "train.csv").open()))
    assert "reach_stage_1" in rows[-1] and "beyond_rate_0" in rows[-1]

    ck = learn / "checkpoints" / "reward.pt"
    p = _run(
        "drs-reuse",
        *TINY,
        "reward=drs",
        f"reward.checkpoint={ck}",
        "env.split=test",
        f"hydra.run.dir={reuse}",
        cwd=tmp_path,
    )
    assert p.returncode == 0, p.stderr[-3000:]
    assert json.loads((reuse / "summary.json").read_text())["updates"] > 0
    assert "split: test" in (reuse / "config.yaml").read_text()  # front leg damping x1.5
