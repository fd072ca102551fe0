"""``drs-quickstart``, the README's first command: learn on the train map, reuse beside the baselines,
figure and summary; interrupted runs exit 130 and continue; other settings in the same folder are refused."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from drs_torchrl.tools.quickstart import QuickstartError, plan, prepare_out

ROOT = Path(__file__).resolve().parents[1]
TINY = (
    'extra=["num_envs=8","max_steps=40","dqn.frames_per_batch=128","dqn.learning_starts=256","dqn.batch_size=32",'
    '"eval.interval=512","eval.episodes=8","reward.stage_buffer_size=4000","reward.disc.batch_size=32","demos=10"]'
)


def _cmd(out: Path, *overrides: str) -> list[str]:
    exe = Path(sys.executable).parent / "drs-quickstart"
    base = [str(exe)] if exe.exists() else [sys.executable, "-m", "drs_torchrl.tools.quickstart"]
    return [*base, f"out={out}", "total_frames=1024", "baselines=[sparse]", TINY, *overrides]


@pytest.mark.sim
@pytest.mark.slow
def test_quickstart_learns_reuses_summarises_and_continues_after_an_interrupt(tmp_path):
    out = tmp_path / "qs"
    env = {**os.environ, "HYDRA_FULL_ERROR": "1"}
    # interrupted once phase 1 has finished: exit 130, phase 1 kept
    proc = subprocess.Popen(_cmd(out), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    deadline = time.time() + 150
    while not (out / "learn" / "summary.json").is_file() and time.time() < deadline and proc.poll() is None:
        time.sleep(0.5)
    assert (out / "learn" / "summary.json").is_file(), proc.communicate(timeout=60)
    if proc.poll() is None:  # phase 2's runs and the figure are still ahead: interrupted
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 130, err
        assert "Run the same command again to continue" in err
        assert not list(out.glob("*/checkpoints")), "a stopped run starts again: it saves no training state"
    else:  # a machine fast enough to end it all within the half-second poll: a finished quickstart
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 0, err
    # the same command continues and ends with the figure and the summary
    done = subprocess.run(_cmd(out), capture_output=True, text=True, env=env, timeout=240, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "learn: finished earlier, kept" in done.stdout
    assert "Phase 2, test map" in done.stdout and "DrS (frozen, reused)" in done.stdout and "sparse" in done.stdout
    assert "Traceback" not in done.stdout + done.stderr
    assert "LazyTensorStorage" not in (out / "logs" / "learn.log").read_text()  # library notices filtered
    assert (out / "quickstart.png").read_bytes()[:4] == b"\x89PNG"
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["phase2"]) == {"drs", "sparse"}
    assert summary["frames_per_run"] == 1024 and summary["phase1"]["disc_updates"] > 0
    assert Path(summary["phase1"]["reward_checkpoint"]).is_file()
    for run in ("learn", "reuse-drs", "reuse-sparse"):
        assert (out / run / "train.csv").is_file(), run
    drs_cfg = (out / "reuse-drs" / "config.yaml").read_text()
    assert str(out / "learn" / "reward.pt") in drs_cfg and "loss_function: l2" in drs_cfg
    # the folder holds this quickstart: other settings are refused, and nothing is touched
    before = (out / "learn" / "summary.json").read_text()
    bad = subprocess.run(_cmd(out, "seed=1"), capture_output=True, text=True, env=env, timeout=60, check=False)
    assert bad.returncode == 2 and "other settings" in bad.stderr and "overwrite=true" in bad.stderr
    assert (out / "learn" / "summary.json").read_text() == before


def test_quickstart_plan_and_bad_settings(tmp_path):
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base=None):
        cfg = compose("quickstart", overrides=["seed=3", "baselines=[dense]"])
        jobs = plan(cfg, tmp_path)
        assert [j.name for j in jobs] == ["learn", "reuse-dense", "reuse-drs"]
        assert jobs[2].needs == ["learn"] and f"reward.checkpoint={tmp_path / 'learn' / 'reward.pt'}" in jobs[2].args
        assert all("seed=3" in j.args for j in jobs)
        assert "dqn.loss_function=smooth_l1" in jobs[0].args and all("dqn.loss_function=l2" in j.args for j in jobs[1:])
        with pytest.raises(QuickstartError, match="unknown baselines"):
            plan(compose("quickstart", overrides=["baselines=[gail]"]), tmp_path)
        with pytest.raises(QuickstartError, match="must be integers"):
            plan(compose("quickstart", overrides=["seed=abc"]), tmp_path)
        for override, message in (  # each had started runs that failed (seed=-1) or crashed (a TypeError)
            ("seed=-1", "seed must be >= 0"),
            ("learn=5", "learn must be a list of drs-maze overrides"),
            ("baselines=sparse", "baselines must be a list, e.g. baselines=[sparse,semi_sparse], got 'sparse'"),
            ("reuse.sparse=x", "reuse maps each phase-2 reward to its drs-maze overrides"),
        ):
            with pytest.raises(QuickstartError) as e:
                plan(compose("quickstart", overrides=[override]), tmp_path)
            assert message in str(e.value)
    other = tmp_path / "other"
    other.mkdir()
    (other / "config.yaml").write_text("phase: learn\n")  # e.g. a drs-learn run
    with pytest.raises(QuickstartError, match="not a quickstart"):
        prepare_out(other, jobs, overwrite=True)
    assert (other / "config.yaml").is_file()


def test_a_refused_quickstart_removes_only_the_folder_it_made(cli, tmp_path):
    """Refused before anything runs: the folder Hydra made for ``out`` goes, an (empty) folder the user made stays."""
    made, mine = tmp_path / "made", tmp_path / "mine"
    mine.mkdir()
    for out in (made, mine):
        code, err = cli("quickstart", f"out={out}", "+baseline=[dense]")
        assert code == 2 and "did you mean baselines=" in err, err
    assert not made.exists()
    assert mine.is_dir() and not any(mine.iterdir())


def test_an_unfinished_run_still_written_by_a_process_is_not_deleted(tmp_path):
    """A re-run deletes an unfinished run's folder to start it again, but not while a process still writes it (a run
    left behind by a quickstart killed outright): the run's own lock names it."""
    from drs_torchrl.tools.quickstart import remove_run

    held, free = tmp_path / "learn", tmp_path / "reuse-sparse"
    free.mkdir()
    (free / "train.csv").write_text("step\n")
    remove_run(free)
    assert not free.exists()
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time; from drs_torchrl.runtime.rundir import lock_run_dir; "
            f"lock_run_dir({str(held)!r}); print('locked', flush=True); time.sleep(60)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        (held / "train.csv").write_text("step\n")
        with pytest.raises(
            QuickstartError, match=f"pid {holder.pid}\\); wait for it to end or stop it, or choose another"
        ):
            remove_run(held)
        assert (held / "train.csv").is_file()
    finally:
        holder.kill()
        holder.wait()
    remove_run(held)  # its writer gone: the folder goes
    assert not held.exists()


def test_progress_prints_one_line_per_evaluation_without_a_terminal(capsys):
    from drs_torchrl.tools.quickstart import Job, Progress

    p = Progress(1000, None)  # pytest's captured stdout is no terminal: lines, not bars
    assert p.bars is False
    job = Job("learn", "phase 1: DrS learns (train map)", [])
    p.start(job)
    row = {"frames": "500", "eval_success": "0.25", "train_success": "0.5", "disc_accuracy": "0.75"}
    p.update(job, row)
    p.update(job, row)  # the same row again: nothing new to say
    p.end(job, True)
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 3 and "started" in lines[0] and lines[-1].endswith("done")
    assert "500 steps, eval success 0.25, train success 0.50, disc acc 0.75" in lines[1]


@pytest.mark.sim
@pytest.mark.slow
def test_a_failed_run_stops_the_others_and_names_its_log(tmp_path):
    out = tmp_path / "qs"
    # the baseline fails at once (bad reward name) while phase 1 is still running beside it
    p = subprocess.run(
        _cmd(out, "total_frames=200000", 'reuse.sparse=["reward.name=nonsense"]'),
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert p.returncode == 1, p.stderr[-2000:]
    assert "run reuse-sparse failed" in p.stderr and "reward.name must be one of" in p.stderr
    assert str(out / "logs" / "reuse-sparse.log") in p.stderr
    assert not (out / "learn" / "summary.json").exists()  # phase 1 was stopped, not left running
    ps = subprocess.run(["ps", "-eo", "args"], capture_output=True, text=True, check=True).stdout
    assert str(out) not in ps


def test_the_record_printed_under_every_summary_is_the_committed_runs():
    """conf/quickstart.yaml `record` (the spread over seeds that each summary prints) matches the committed
    summary.json of each seed, to two decimals; a seed's record lives under results/quickstart/ or
    results/first_command/ (selection/: seeds 3-4, test/: seeds 5-9)."""
    import json

    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from drs_torchrl.tools.quickstart import spread_text
    from drs_torchrl.config_dir import conf_dir

    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        record = OmegaConf.to_container(compose("quickstart").record)
    assert set(record) >= {"drs", "sparse", "semi_sparse"} and len(record["drs"]) >= 3
    for name, by_seed in record.items():
        for seed, value in by_seed.items():
            found = [
                p
                for p in (
                    ROOT / "results" / "quickstart" / f"seed{seed}",
                    ROOT / "results" / "first_command" / "selection" / f"seed{seed}",
                    ROOT / "results" / "first_command" / "test" / f"seed{seed}",
                )
                if (p / "summary.json").is_file() and name in json.loads((p / "summary.json").read_text())["phase2"]
            ]
            assert found, (name, seed)
            got = json.loads((found[0] / "summary.json").read_text())["phase2"][name]["success_last3"]
            assert round(got, 2) == value, (name, seed, got, value)
    text = "\n".join(spread_text(record))
    hits = sum(v >= 0.9 for v in record["drs"].values())
    assert f"DrS (frozen, reused) >= 0.9 in {hits} of {len(record['drs'])}" in text
