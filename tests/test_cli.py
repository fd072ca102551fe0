"""drs-learn and drs-reuse through their console scripts, on real ManiSkill at tiny budgets."""

import csv
import shutil
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from drs_torchrl.transforms import DrSReward
from budgets import small


BIN = Path(sys.executable).parent
TINY = small(disc_batch=None, eval_every=512, checkpoint_every=512)
DEFAULT_COLLECTOR = small(disc_batch=None, eval_every=512, checkpoint_every=512, background=True)  # the config's own
DISC = ["reward.disc.batch_size=32"]


def run(cmd, *args, cwd):
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    return subprocess.run([str(BIN / cmd), *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def learned(tmp_path_factory):
    d = tmp_path_factory.mktemp("learn")
    # a wide placement threshold makes "placed" trajectories likely even under random actions
    p = run(
        "drs-learn",
        *DEFAULT_COLLECTOR,
        *DISC,
        "logger.tensorboard=true",
        "+env.variant_overrides.goal_thresh=0.08",
        f"hydra.run.dir={d}",
        "seed=1",
        cwd=d,
    )
    assert p.returncode == 0, p.stderr[-3000:]
    return d


@pytest.mark.sim
@pytest.mark.slow
def test_learn_writes_reward_policy_logs_and_config(learned):
    assert (learned / "checkpoints" / "reward.pt").is_file()
    assert (learned / "checkpoints" / "policy.pt").is_file()
    assert (learned / "config.yaml").is_file()
    assert list((learned / "tb").glob("events.*"))
    rows = list(csv.DictReader((learned / "train.csv").open()))
    assert int(rows[-1]["frames"].split(".")[0]) >= 640
    for col in (
        "success_rate",
        "reach_stage_1",
        "reach_stage_3",
        "env_steps_per_s",
        "updates_per_s",
        "stage_buffer_0",
        "reward_mean",
    ):
        assert col in rows[-1], col
    timed = [r for r in rows if r.get("frac_time_waiting_for_data")]  # TorchRL timeit's drs/collect and drs/update
    assert timed and all(
        0 < float(r["frac_time_waiting_for_data"]) <= 1 and float(r["collect_steps_per_s"]) > 0 for r in timed
    )
    summary = json.loads((learned / "summary.json").read_text())
    assert summary["frames"] >= 640 and summary["updates"] > 0
    head = subprocess.run(
        ["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=Path(__file__).parent
    ).stdout.strip()
    assert summary["code"]["commit"] == (head or None)  # the code behind the run (None outside a git checkout)
    eps = summary["stage_buffer_episodes"]
    assert sum(eps) >= 10
    # a discriminator trains iff it has trajectories on both sides of its stage
    trainable = any(sum(eps[: k + 1]) > 0 and sum(eps[k + 1 :]) > 0 for k in range(3))
    assert (summary["disc_updates"] > 0) == trainable, eps
    reward = DrSReward.from_checkpoint(learned / "checkpoints" / "reward.pt")
    assert reward.metadata["family"] == "pick_cube" and reward.num_stages == 3
    assert reward.in_shapes == {"observation": 42, "stage_indicators": 3}


@pytest.mark.sim
@pytest.mark.slow
def test_reuse_loads_the_learned_reward_on_the_test_variant_and_trains(learned, tmp_path):
    ck = learned / "checkpoints" / "reward.pt"
    p = run("drs-reuse", *TINY, "reward=drs", f"reward.checkpoint={ck}", f"hydra.run.dir={tmp_path}", cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["updates"] > 0
    cfg = (tmp_path / "config.yaml").read_text()
    assert "split: test" in cfg
    # the rewards SAC trained on come from the frozen learned reward: rescaled range is [-2-1/9, -1]
    rows = list(csv.DictReader((tmp_path / "train.csv").open()))
    lo = [float(x["reward_min"]) for x in rows if x.get("reward_min")]
    hi = [float(x["reward_max"]) for x in rows if x.get("reward_max")]
    assert lo and min(lo) >= -2 - 1 / 9 - 1e-4 and max(hi) <= -1 + 1e-4  # not ManiSkill's 0/1 sparse reward
    assert (tmp_path / "checkpoints" / "policy.pt").is_file()


@pytest.mark.sim
@pytest.mark.slow
def test_compare_and_plot_read_real_runs(learned, tmp_path):
    twin = tmp_path / "twin"  # a second run directory with the same records (one run named twice is refused)
    twin.mkdir()
    for name in ("config.yaml", "train.csv", "eval.csv"):
        shutil.copy(learned / name, twin / name)
    p = run(
        "drs-compare",
        str(learned),
        str(twin),
        "--group-by",
        "phase",
        "env.split",
        "--out",
        str(tmp_path),
        cwd=tmp_path,
    )
    assert p.returncode == 0, p.stderr[-3000:]
    rows = list(csv.DictReader((tmp_path / "compare.csv").open()))
    ev = [r for r in rows if r["source"] == "eval" and r["metric"] == "success_rate"]
    assert (
        ev
        and {r["group"] for r in rows} == {"learn train"}
        and all(r["n"] == "2" and float(r["std"]) == 0.0 for r in ev)
    )
    assert "| learn train | 2 (1, 1) |" in (tmp_path / "compare.md").read_text()
    assert (tmp_path / "compare.png").stat().st_size > 10_000
    p = run("drs-plot", str(learned), "--out", str(tmp_path / "progress.png"), cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    assert (tmp_path / "progress.png").stat().st_size > 10_000


@pytest.mark.sim
@pytest.mark.slow
@pytest.mark.parametrize("baseline", ["semi_sparse", "dense"])
def test_reuse_with_baseline_rewards(baseline, tmp_path):
    p = run("drs-reuse", *TINY, f"reward={baseline}", "total_frames=384", f"hydra.run.dir={tmp_path}", cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    rows = [x for x in csv.DictReader((tmp_path / "train.csv").open()) if x.get("reward_max")]
    lo = min(float(x["reward_min"]) for x in rows)
    hi = max(float(x["reward_max"]) for x in rows)
    if baseline == "semi_sparse":
        assert lo == -3.0 and hi <= 0.0  # k - N: stage-0 states get -3
    else:
        # normalized dense minus 1 (reward/dense.yaml): the reaching term keeps it above -1, success earns 0
        assert -1.0 < lo and hi <= 0.0


@pytest.mark.sim
@pytest.mark.slow
def test_reuse_rejects_a_checkpoint_that_does_not_fit(learned, tmp_path, cli):
    """(In this process; the console script's one line for it: results/bad_inputs/, its table test.)"""
    r = DrSReward.from_checkpoint(learned / "checkpoints" / "reward.pt")
    wrong = DrSReward(3, ["observation"], {"observation": 40}, metadata={"family": "pick_cube"})
    wrong.save(tmp_path / "wrong.pt")
    code, err = cli("reuse", *TINY, f"reward.checkpoint={tmp_path / 'wrong.pt'}", f"hydra.run.dir={tmp_path / 'run'}")
    assert code == 2
    assert "size 40" in err and "size 42" in err
    assert not (tmp_path / "run" / "checkpoints" / "policy.pt").exists()
    assert r.num_stages == 3


def test_reuse_without_checkpoint_and_bad_values_fail_clearly(tmp_path, cli):
    # the app in this process (each stops before simulating; the console scripts' one line: results/bad_inputs/)
    code, err = cli("reuse", *TINY, f"hydra.run.dir={tmp_path / 'a'}")
    assert code == 2 and "drs-reuse: error: drs-reuse with reward=drs needs reward.checkpoint=PATH" in err
    # (the schema's refusals, total_frames=-5, buffer_size, stop_at_success, ...: test_schema.py, once)
    for args, expect in [
        (["reward.alpha=0.6"], "alpha=0.6 breaks the stage ordering"),
        (["env.family=nope"], "unknown task family 'nope'"),
        (["env.split=cube_9cm"], "no variant 'cube_9cm'"),
        (["demos.sac_share=most"], "demos.sac_share must be auto or a number in [0, 1)"),
    ]:
        code, err = cli("learn", *TINY, *args, f"hydra.run.dir={tmp_path / 'b'}")
        assert code == 2 and expect in err, (args, code, err[-2000:])
        assert not (tmp_path / "b" / "config.yaml").exists()
    code, err = cli("learn", *TINY, "algo.batchsize=3", f"hydra.run.dir={tmp_path / 'e'}")
    assert code != 0 and "batchsize" in err
    code, err = cli("learn", *TINY, "reward=vice", f"hydra.run.dir={tmp_path / 'g'}")
    assert code != 0 and "Could not find 'reward/vice'" in err and "semi_sparse" in err


@pytest.mark.sim
@pytest.mark.slow
def test_learn_with_two_cpu_envs(tmp_path):
    p = run(
        "drs-learn",
        *TINY,
        *DISC,
        "env.num_envs=2",
        "total_frames=384",
        "algo.learning_starts=128",
        f"hydra.run.dir={tmp_path}",
        cwd=tmp_path,
    )
    assert p.returncode == 0, p.stderr[-3000:]
    summary = json.loads((tmp_path / "summary.json").read_text())
    # 384 steps over two envs = 192 per env: three finished 50-step episodes each (unless one
    # succeeds early); assembled per env, so no episode is longer than 50 steps
    eps, trans = summary["stage_buffer_episodes"], summary["stage_buffer_transitions"]
    assert summary["frames"] == 384 and sum(eps) >= 6
    assert sum(trans) <= 50 * sum(eps)
    rows = [x for x in csv.DictReader((tmp_path / "train.csv").open()) if x.get("episode_length")]
    assert all(float(x["episode_length"]) <= 50 for x in rows)


@pytest.mark.sim
@pytest.mark.slow
def test_no_vulkan_device_says_how_to_install_one(tmp_path):
    env = dict(os.environ, PYTHONWARNINGS="ignore", VK_ICD_FILENAMES=str(tmp_path / "no_driver.json"))
    p = subprocess.run(
        [str(BIN / "drs-learn"), *TINY, f"hydra.run.dir={tmp_path / 'run'}"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert p.returncode == 2
    assert "No usable Vulkan device" in p.stderr and "mesa-vulkan-drivers" in p.stderr
    p = subprocess.run([str(BIN / "drs-doctor")], env=env, capture_output=True, text=True, timeout=300)
    assert p.returncode == 2 and "bookworm-backports" in p.stderr


@pytest.mark.sim
@pytest.mark.slow
def test_a_reward_on_the_task_state_only_learns_and_is_reused(tmp_path):
    """reward.in_keys=[task_observation,stage_indicators]: the env writes the task state by itself (saved in
    config.yaml), the discriminators read no joint positions or velocities, and drs-reuse turns it on again."""
    learn, reuse = tmp_path / "learn", tmp_path / "reuse"
    p = run(
        "drs-learn",
        *TINY,
        *DISC,
        "reward.in_keys=[task_observation,stage_indicators]",
        f"hydra.run.dir={learn}",
        cwd=tmp_path,
    )
    assert p.returncode == 0, p.stderr[-3000:]
    from omegaconf import OmegaConf

    assert OmegaConf.load(learn / "config.yaml").env.task_observation is True
    reward = DrSReward.from_checkpoint(learn / "checkpoints" / "reward.pt")
    assert reward.in_shapes == {"task_observation": 19, "stage_indicators": 3}
    p = run(
        "drs-reuse",
        *TINY,
        "env.split=test",
        "total_frames=384",
        f"reward.checkpoint={learn / 'checkpoints' / 'reward.pt'}",
        f"hydra.run.dir={reuse}",
        cwd=tmp_path,
    )
    assert p.returncode == 0, p.stderr[-3000:]
    assert OmegaConf.load(reuse / "config.yaml").env.task_observation is True
    rows = [x for x in csv.DictReader((reuse / "train.csv").open()) if x.get("reward_max")]
    # the rescaled Eq. 4 with N = 3: (k + tanh(D_k)/3)/3 - 2, in [-2.12, 0)
    assert rows and all(-2.12 <= float(x["reward_min"]) <= float(x["reward_max"]) < 0 for x in rows)
