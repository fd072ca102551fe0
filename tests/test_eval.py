"""drs-eval: deterministic episodes of a trained run on any split, with ManiSkill's metrics and mp4 video."""

import json
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import pytest
from budgets import tiny


BIN = Path(sys.executable).parent
TINY = [*tiny(eval_episodes=0), "env.max_episode_steps=20"]


def run(cmd, *args, cwd):
    return subprocess.run([str(BIN / cmd), *args], cwd=cwd, capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    d = tmp_path_factory.mktemp("run")
    p = run("drs-learn", *TINY, f"hydra.run.dir={d}", cwd=d)
    assert p.returncode == 0, p.stderr[-3000:]
    return d


@pytest.mark.sim
@pytest.mark.slow
def test_eval_reports_maniskill_metrics_on_the_held_out_split(trained):
    p = run("drs-eval", str(trained), "--episodes", "3", "--split", "test", cwd=trained)
    assert p.returncode == 0, p.stderr[-2000:]
    assert "success_once" in p.stdout and "success_at_end" in p.stdout and "stage>=3" in p.stdout
    res = json.loads((trained / "eval_test.json").read_text())
    assert res["split"] == "test" and res["episodes"] == 3 and len(res["rows"]) == 3 and res["seed"] == 12345
    for row in res["rows"]:
        assert 1 <= row["length"] <= 20
        assert row["success_at_end"] <= row["success_once"]
        # the return is under the run's learned reward: (k + tanh(D_k)/3)/3 - 2 per step, so within these bounds
        assert -2.12 * row["length"] <= row["return"] <= -0.99 * row["length"]
    assert res["success_once"] == sum(r["success_once"] for r in res["rows"]) / 3


@pytest.mark.sim
@pytest.mark.slow
def test_eval_records_one_mp4_frame_per_step(trained, tmp_path):
    p = run(
        "drs-eval",
        str(trained),
        "--episodes",
        "1",
        "--video",
        str(tmp_path / "v"),
        "--out",
        str(tmp_path / "r.json"),
        cwd=trained,
    )
    assert p.returncode == 0, p.stderr[-2000:]
    row = json.loads((tmp_path / "r.json").read_text())["rows"][0]
    frames = list(iio.imiter(row["video"]))
    # the start state, then one frame after each step
    assert len(frames) == row["length"] + 1 and frames[0].ndim == 3 and frames[0].shape[-1] == 3
    assert frames[0].std() > 1  # a picture, not a blank frame


@pytest.mark.sim
@pytest.mark.slow
def test_eval_episode_seed_fixes_each_episode_start(trained, tmp_path):
    """--episode-seed S: episode i starts from seed S+i, whatever the number of episodes before it."""
    rows = {}
    for name, args in {
        "5x2": ["--episode-seed", "5", "--episodes", "2"],
        "6x1": ["--episode-seed", "6", "--episodes", "1"],
        "5x1": ["--episode-seed", "5", "--episodes", "1"],
    }.items():
        p = run(
            "drs-eval", str(trained), "--split", "test", *args, "--out", str(tmp_path / f"{name}.json"), cwd=trained
        )
        assert p.returncode == 0, p.stderr[-2000:]
        rows[name] = json.loads((tmp_path / f"{name}.json").read_text())["rows"]
    assert [r["seed"] for r in rows["5x2"]] == [5, 6]
    same = ("start", "length", "return", "stage", "success_once")
    assert {k: rows["5x2"][1][k] for k in same} == {k: rows["6x1"][0][k] for k in same}
    assert {k: rows["5x2"][0][k] for k in same} == {k: rows["5x1"][0][k] for k in same}
    assert rows["5x2"][0]["start"] != rows["5x2"][1]["start"]  # two different starts


@pytest.mark.parametrize(
    "args,message",
    [
        (["--split", "cube_9cm"], "no variant 'cube_9cm'"),
        (["--episodes", "0"], "argument --episodes: must be >= 1, got 0"),
        (["--episode-seed", "-1"], "argument --episode-seed: must be >= 0, got -1"),
    ],
)
@pytest.mark.sim
@pytest.mark.slow
def test_eval_bad_input_is_one_line(trained, args, message):
    p = run("drs-eval", str(trained), *args, cwd=trained)
    assert p.returncode == 2 and message in p.stderr and "Traceback" not in p.stderr


def test_eval_refuses_a_directory_that_is_not_a_run(tmp_path):
    p = run("drs-eval", str(tmp_path), cwd=tmp_path)
    assert p.returncode == 2 and "not a drs-learn/drs-reuse run directory" in p.stderr


@pytest.mark.sim
@pytest.mark.slow
def test_reward_episode_figure_is_drawn_from_a_real_episode(trained, tmp_path):
    out = tmp_path / "fig3.png"
    p = run("drs-plot", str(trained), "--reward-episode", "--tries", "2", "--out", str(out), cwd=trained)
    assert p.returncode == 0, p.stderr[-2000:]
    img = iio.imread(out)
    assert img.shape[0] > 200 and img.shape[1] > 400 and img.std() > 5


@pytest.mark.sim
@pytest.mark.slow
def test_eval_reads_a_committed_record(trained, tmp_path):
    """drs-study --report flattens a run into config.yaml, policy.pt and reward.pt side by side; drs-eval takes that too."""
    import shutil

    rec = tmp_path / "record"
    rec.mkdir()
    for src in ("config.yaml", "checkpoints/policy.pt", "checkpoints/reward.pt"):
        shutil.copy(trained / src, rec / Path(src).name)
    p = run("drs-eval", str(rec), "--episodes", "1", cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-2000:]
    assert json.loads((rec / "eval_train.json").read_text())["rows"][0]["return"] < 0  # under the learned reward


@pytest.mark.sim
@pytest.mark.slow
def test_reward_probe_reports_every_stage_with_a_rank_correlation(trained, tmp_path):
    """The probe reads discriminator k at the states of stage k: with each discriminator made a constant c_k (its
    last layer zero but the bias), every stage-k state's tanh(D_k) is tanh(c_k), and no other discriminator's."""
    import math

    import torch

    from drs_torchrl.transforms import DrSReward

    reward = DrSReward.from_checkpoint(trained / "checkpoints" / "reward.pt")
    constants = [0.5, -2.0, 3.0]  # tanh: 0.462, -0.964, 0.995
    with torch.no_grad():
        for net, c in zip(reward.discriminators.nets, constants):
            net[-1].weight.zero_()
            net[-1].bias.fill_(c)
    reward.save(tmp_path / "constant.pt")
    p = subprocess.run(
        [
            sys.executable,
            "-m",
            "drs_torchrl.tools.probe",
            "--reward",
            str(tmp_path / "constant.pt"),
            "--policy",
            str(trained),
            "--splits",
            "test",
            "--episodes",
            "2",
            "--out",
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=tmp_path,
    )
    assert p.returncode == 0, p.stderr[-2000:]
    res = json.loads((tmp_path / "probe.json").read_text())
    stages = res["splits"]["test"]["stages"]
    assert [s["stage"] for s in stages] == [0, 1, 2]
    assert sum(s["states"] for s in stages) >= 2  # two episodes of at most 20 steps, none ending before a step
    assert stages[0]["states"] >= 1  # every episode starts at stage 0
    for s, c in zip(stages, constants):
        if s["states"]:
            for key in ("tanh_d_mean", "tanh_d_min", "tanh_d_max"):
                assert s[key] == pytest.approx(math.tanh(c), abs=1e-6), (s, c)
        else:
            assert math.isnan(s["tanh_d_mean"])
    assert (tmp_path / "probe.png").stat().st_size > 1000 and "Spearman" in (tmp_path / "probe.md").read_text()


@pytest.mark.sim
@pytest.mark.slow
def test_reward_probe_labels_stages_with_a_variant_override_that_reaches_the_env(trained, tmp_path):
    """--variant-override placed_thresh=... labels the stages as a reward learned at that threshold does."""

    def probe(*extra):
        return subprocess.run(
            [
                sys.executable,
                "-m",
                "drs_torchrl.tools.probe",
                "--reward",
                str(trained / "checkpoints" / "reward.pt"),
                "--policy",
                str(trained),
                "--splits",
                "test",
                "--episodes",
                "1",
                "--out",
                str(tmp_path),
                *extra,
            ],
            capture_output=True,
            text=True,
            timeout=600,
            cwd=tmp_path,
        )

    p = probe("--variant-override", "placed_thresh=0.05")
    assert p.returncode == 0, p.stderr[-2000:]
    assert json.loads((tmp_path / "probe.json").read_text())["variant_overrides"] == {"placed_thresh": 0.05}
    assert "{'placed_thresh': 0.05} (stages labelled with them)" in (tmp_path / "probe.md").read_text()
    p = probe("--variant-override", "placed_thresh=-1")  # the env itself refuses it: the override got there
    assert p.returncode != 0 and "placed_thresh must be >= 0" in p.stderr
    p = probe("--variant-override", "placed_thresh")
    assert p.returncode == 2 and "KEY=VALUE" in p.stderr


def test_spearman_of_the_probe_ranks_and_refuses_degenerate_inputs():
    from drs_torchrl.tools.probe import spearman

    import numpy as np

    x = np.array([0.1, 0.5, 0.2, 0.9])
    assert spearman(x, x**3) == pytest.approx(1.0) and spearman(x, -x) == pytest.approx(-1.0)
    assert np.isnan(spearman(x, np.ones(4))) and np.isnan(spearman(x[:2], x[:2]))


def test_feature_swap_finds_the_inputs_a_score_reads():
    """A score that reads column 2 only: swapping that group moves each side to the other's level, the rest do nothing."""
    import torch
    from drs_torchrl.tools.probe import feature_swap

    fa, fb = torch.zeros(50, 4), torch.zeros(40, 4)
    fa[:, 2], fb[:, 2] = 1.0, -1.0
    fa[:, 0], fb[:, 0] = torch.randn(50), torch.randn(40) + 5

    rows = {
        r["group"]: r
        for r in feature_swap(lambda f: torch.tanh(f[:, 2]), fa, fb, {"x": (0, 2), "v": (2, 3), "g": (3, 4)})
    }
    assert rows["(none)"]["a"] == pytest.approx(0.7616, abs=1e-3) and rows["(none)"]["b"] == pytest.approx(
        -0.7616, abs=1e-3
    )
    assert rows["v"]["a"] == pytest.approx(-0.7616, abs=1e-3) and rows["v"]["b"] == pytest.approx(0.7616, abs=1e-3)
    for g in ("x", "g"):
        assert (rows[g]["a"], rows[g]["b"]) == (rows["(none)"]["a"], rows["(none)"]["b"])
    assert rows["v"]["norm_a"] == pytest.approx(1.0) and rows["v"]["norm_b"] == pytest.approx(1.0)
    assert rows["g"]["norm_a"] == 0.0


def test_feature_groups_name_every_column_of_the_pick_reward_input():
    from drs_torchrl.tools.probe import feature_groups

    from drs_torchrl.tasks import get_family
    from drs_torchrl.transforms import DrSReward

    fam = get_family("pick_cube")
    groups = feature_groups(
        fam, DrSReward(3, ["observation", "stage_indicators"], {"observation": 42, "stage_indicators": 3})
    )
    spans = sorted(groups.values())
    assert spans[0][0] == 0 and spans[-1][1] == 45 and all(a[1] == b[0] for a, b in zip(spans, spans[1:]))
    assert groups["joint velocities"] == (9, 18) and groups["stage_indicators"] == (42, 45)
    task = feature_groups(
        fam, DrSReward(3, ["task_observation", "stage_indicators"], {"task_observation": 19, "stage_indicators": 3})
    )
    assert task["object to goal"] == (16, 19) and task["stage_indicators"] == (19, 22)
    # an input the family names no layout for is one group
    valve = feature_groups(
        get_family("turn_valve"),
        DrSReward(2, ["observation", "stage_indicators"], {"observation": 30, "stage_indicators": 2}),
    )
    assert valve == {"observation": (0, 30), "stage_indicators": (30, 32)}


def _training_evaluations(tmp_path, *overrides):
    """The start observations of two in-training evaluations (3 episodes each), with torch's global RNG
    moved in between as learner updates move it."""
    import torch
    from hydra import compose, initialize_config_dir

    from drs_torchrl.apps.cli import conf_dir
    from drs_torchrl.apps.build import Run

    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        cfg = compose(
            "reuse",
            overrides=[
                "reward=semi_sparse",
                "algo.hidden=[16,16]",
                "eval.episodes=3",
                "env.max_episode_steps=5",
                "logger.progress_bar=false",
                "logger.tensorboard=false",
                "algo.collector._target_=torchrl.collectors.Collector",
                *overrides,
            ],
        )
    tr = Run(cfg, "reuse", tmp_path)
    starts, rollout = [], tr.eval_env.rollout

    def recording_rollout(*args, **kwargs):
        ep = rollout(*args, **kwargs)
        starts.append(ep[0]["observation"].clone())
        return ep

    tr.eval_env.rollout = recording_rollout
    try:
        tr.evaluate()
        torch.rand(1000)
        tr.evaluate()
    finally:
        tr.close()
    return starts


@pytest.mark.sim
@pytest.mark.slow
def test_training_evaluations_replay_the_same_episodes_with_episode_seed(tmp_path):
    import torch

    seeded = _training_evaluations(tmp_path / "seeded", "eval.episode_seed=100")
    first, second = seeded[:3], seeded[3:]
    assert all(torch.equal(a, b) for a, b in zip(first, second))  # the same 3 episodes at both evaluations
    assert not torch.equal(first[0], first[1])  # distinct episodes within one evaluation
    unseeded = _training_evaluations(tmp_path / "unseeded")
    assert not all(torch.equal(a, b) for a, b in zip(unseeded[:3], unseeded[3:]))  # the default: new episodes


@pytest.mark.parametrize("damaged", [False, True])
def test_eval_report_name_keeps_an_earlier_report_made_with_other_settings(tmp_path, damaged):
    """drs-eval's default report: --override values name it; an earlier report with other --episodes (or one
    that cannot be read) is kept and the new one takes the next free name; the same measurement replaces its own."""
    from drs_torchrl.apps.evaluate import report_path

    def res(episodes=1, **overrides):
        return {
            "run_dir": str(tmp_path),
            "split": "test",
            "overrides": overrides,
            "episodes": episodes,
            "episode_seed": 0,
            "seed": 12345,
            "deterministic": True,
            "policy_frames": 2000,
        }

    first = tmp_path / "eval_test.json"
    first.write_text("{not json" if damaged else json.dumps(res(episodes=1)))
    assert report_path(res(episodes=2)) == (tmp_path / "eval_test_2.json", first)
    (tmp_path / "eval_test_2.json").write_text(json.dumps(res(episodes=2)))
    assert report_path(res(episodes=2)) == (tmp_path / "eval_test_2.json", first)
    assert report_path(res(episodes=3)) == (tmp_path / "eval_test_3.json", first)
    if not damaged:
        assert report_path(res(episodes=1)) == (first, None)  # the same measurement again: its own report
    assert report_path(res(cube_half_size=0.02)) == (tmp_path / "eval_test_cube_half_size=0.02.json", None)
