"""drs-bench's roofline: the bound it reports follows from the measured GEMM rate and FLOP count."""

import os

import pytest

from drs_torchrl.tools.bench import render_markdown, roofline


def test_roofline_bound_is_the_core_time_formula(monkeypatch):
    # the formula given a GEMM rate: a fixed rate instead of timing GEMMs at every precision and core count
    # (110 s where bf16 is emulated and another test holds the second core); gemm_gflops itself runs in drs-bench
    import drs_torchrl.tools.bench as bench

    monkeypatch.setattr(bench, "gemm_gflops", lambda batch, width, threads, dtype=None: 100.0 * threads)
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    res = {
        "raw_sim_steps_per_s": 500.0,
        "learn": [{"algo": "sac_cpu", "utd": 0.5}],
        "plain": [{"batch_size": 256, "env_steps_per_s": 100.0, "updates_per_s_overall": 50.0}],
        "components": [
            {"algo": "sac_cpu", "batch_size": 256, "width": 256, "sac_update_gflop": 1.6, "sac_update_ms": 15.0}
        ],
    }
    (row,) = roofline(res)
    cores = 2
    # 2 cores / (0.5 updates x 1.6 GFLOP / 100 GFLOP/s + 1/500 s of simulation) per env step = 2 / 0.01
    assert row["gemm_gflops_1_thread"] == 100.0 and row["gemm_gflops_2_threads"] == 200.0
    assert row["env_steps_per_s_bound"] == pytest.approx(200.0)
    assert row["bound_over_plain"] == pytest.approx(2.0)  # over the plain loop's 100 env steps/s
    assert row["update_ms_lower_bound_all_cores"] == pytest.approx(8.0)  # 1.6 GFLOP at 200 GFLOP/s
    assert row["update_ms_measured"] == 15.0 and row["plain_env_steps_per_s"] == 100.0
    # ten times the FLOPs: 2 / (0.5 x 16 / 100 + 1/500) = 2 / 0.082
    res["components"][0]["sac_update_gflop"] = 16.0
    (row2,) = roofline(res)
    assert row2["env_steps_per_s_bound"] == pytest.approx(2 / 0.082)
    res.update(
        command="drs-bench",
        family="pick_cube",
        collect={},
        roofline=[row],
        machine={"cpus": cores, "torch_threads": 1, "platform": "x", "torch": "x", "cuda": False},
    )
    res["learn"] = []
    res["components"] = []
    assert "env steps/s bound" in render_markdown(res)
    # a bracketed plain-loop measurement shows both halves; a bf16 component gets its own roofline row
    res["plain"] = [
        {"batch_size": 256, "env_steps_per_s": 100.0, "updates_per_s_overall": 50.0, "before": 90.0, "after": 110.0}
    ]
    assert "100.0 (before 90.0, after 110.0)" in render_markdown(res)
    comp = {
        "algo": "sac_cpu",
        "batch_size": 256,
        "width": 256,
        "sac_update_gflop": 1.6,
        "sac_update_ms": 15.0,
        "sac_update_ms_by_precision": {"fp32": 15.0, "bf16": 12.0},
    }
    rows = roofline({**res, "components": [comp], "learn": [{"algo": "sac_cpu", "utd": 0.5}]})
    assert [r["precision"] for r in rows] == ["fp32", "bf16"] and rows[1]["update_ms_measured"] == 12.0


def test_fewer_updates_rows_are_compared_with_the_plain_loop_at_the_same_samples_per_step(monkeypatch):
    """A batch-512, UTD-0.25 config is compared with the plain loop at batch 256, UTD 0.5 (the same 128
    gradient samples per env step), and also with the plain loop given the same lever."""
    import drs_torchrl.tools.bench as bench
    from drs_torchrl.tools.bench import algo_settings, parse_algo

    monkeypatch.setattr(bench, "gemm_gflops", lambda batch, width, threads, dtype=None: 100.0 * threads)
    monkeypatch.setattr(os, "cpu_count", lambda: 2)

    assert parse_algo("sac_cpu_utd025:bf16", ["fp32", "bf16"]) == ("sac_cpu_utd025", ["bf16"])
    assert parse_algo("sac_paper", ["fp32", "bf16"]) == ("sac_paper", ["fp32", "bf16"])
    with pytest.raises(SystemExit, match="fp32 or bf16"):
        parse_algo("sac_cpu:fp64", ["fp32"])
    # the plain-loop reference reads the composed config (sac_cpu_utd025 extends sac_cpu through its defaults list)
    assert algo_settings("sac_cpu_utd025") == (512, 0.25, 2, 256) and algo_settings("sac_cpu") == (256, 0.5, 1, 256)
    learn = {
        "algo": "sac_cpu_utd025",
        "utd": 0.25,
        "batch_size": 512,
        "collector": "inproc",
        "precision": "bf16",
        "env_steps_per_s": 130.0,
        "updates_per_s": 32.5,
        "over_plain": 1.3,
        "over_plain_same_updates": 0.9,
        "plain_reference": {"batch_size": 256, "utd": 0.5},
    }
    plain = [
        {"batch_size": 256, "utd": 0.5, "env_steps_per_s": 100.0, "updates_per_s_overall": 50.0},
        {"batch_size": 512, "utd": 0.25, "disc_updates": 2, "env_steps_per_s": 144.0, "updates_per_s_overall": 36.0},
    ]
    comp = {"algo": "sac_cpu_utd025", "batch_size": 512, "width": 256, "sac_update_gflop": 3.2, "sac_update_ms": 30.0}
    res = {"raw_sim_steps_per_s": 500.0, "learn": [learn], "plain": plain, "components": [comp]}
    (row,) = roofline(res)
    cores = 2
    # 2 cores / (0.25 updates x 3.2 GFLOP / 100 GFLOP/s + 1/500 s) per env step = 2 / 0.01
    assert row["utd"] == 0.25 and row["env_steps_per_s_bound"] == pytest.approx(200.0)
    assert row["bound_over_plain"] == pytest.approx(2.0)
    assert row["plain_env_steps_per_s"] == 100.0  # the reference (256, 0.5), not the same-lever loop at 512
    res.update(
        command="drs-bench",
        family="pick_cube",
        collect={},
        roofline=[row],
        machine={"cpus": cores, "torch_threads": 1, "platform": "x", "torch": "x", "cuda": False},
        components=[],
    )
    md = render_markdown(res)
    assert (
        "| phase 1, sac_cpu_utd025 (batch 512, UTD 0.25), inproc collector, bf16 | 130.0 | 32.5 | 1.30x | 0.90x |" in md
    )
    assert (
        "| plain single-file PyTorch DrS loop (batch 512, UTD 0.25, 2 discriminator steps per update), fp32 | 144.0 |"
        in md
    )


@pytest.mark.sim
@pytest.mark.slow
def test_bench_console_is_free_of_library_notices(tmp_path):
    """drs-bench, like the training apps, filters ManiSkill's and TorchRL's routine notices (console.py)."""
    import subprocess
    import sys

    env = {
        k: v for k, v in os.environ.items() if k not in ("RL_WARNINGS", "DRS_LIBRARY_MESSAGES", "DRS_QUIET_LIBRARIES")
    }
    env["OMP_NUM_THREADS"] = "1"
    cmd = [
        sys.executable,
        "-c",
        "import sys; from drs_torchrl.tools.bench import main; sys.exit(main())",
        "--raw-steps",
        "50",
        "--collect-steps",
        "64",
        "--learn-frames",
        "64",
        "--learning-starts",
        "256",
        "--algos",
        "sac_cpu",
        "--collect-collectors",
        "inproc",
        "--collectors",
        "inproc",
        "--precisions",
        "fp32",
        "--stage-sizes",
        "--no-plain",
        "--no-compile",
        "--out",
        str(tmp_path / "bench"),
    ]
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    console = out.stdout + out.stderr
    assert "raw simulator" in console and (tmp_path / "bench" / "bench.json").exists()
    for noise in (
        "UserWarning",
        "Requested to use render device",
        "No initial pose set",
        "Initialized LazyTensorStorage",
    ):
        assert noise not in console, (noise, console[-2000:])


@pytest.mark.slow
@pytest.mark.sim
def test_the_flop_count_runs_on_a_real_phase_1_run(tmp_path):
    """drs-bench's FLOP count of one SAC update reads the run's updater (a tiny real PickCube phase 1)."""
    from hydra import compose, initialize_config_dir

    from drs_torchrl.tools.bench import sac_update_gflop
    from drs_torchrl.apps.build import Run
    from drs_torchrl.config_dir import conf_dir

    tiny = ["total_frames=320", "algo.learning_starts=256", "algo.batch_size=32", "algo.hidden=[32,32]",
            "reward.disc.batch_size=16", "eval.episodes=0", "logger.progress_bar=false", "logger.tensorboard=false",
            "checkpoint_interval=1000000", "algo.collector._target_=torchrl.collectors.Collector"]  # fmt: skip
    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        cfg = compose("learn", overrides=tiny)
    Run(cfg, "learn", tmp_path).run()
    run = Run(cfg, "learn", tmp_path, resume=True)
    try:
        assert len(run.updater.replay) == 320
        # batch 32, hidden 32x32: a few MFLOP of matrix products in the forward and backward passes
        assert 0 < sac_update_gflop(run) < 1
    finally:
        run.close()
