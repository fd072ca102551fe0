"""A real run killed mid-way (SIGKILL) resumes from its last checkpoint with the same state."""

import csv
import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf
from budgets import small, tiny


BIN = Path(sys.executable).parent
TINY = [*small(frames=None, checkpoint_every=512, background=True), "+env.variant_overrides.goal_thresh=0.08"]


def _wait_for_state(run_dir: Path, frames: int, proc, timeout=240):
    marker = run_dir / "checkpoints" / "state" / "COMPLETE"
    t = time.time()
    while time.time() - t < timeout:
        if marker.is_file() and int(marker.read_text() or 0) >= frames:
            return int(marker.read_text())
        assert proc.poll() is None, proc.stderr.read()[-3000:]
        time.sleep(0.2)
    raise TimeoutError("no checkpoint written")


def _steps(path: Path):
    return [int(float(r["step"])) for r in csv.DictReader(path.open())]


@pytest.mark.sim
@pytest.mark.slow
def test_sigkill_then_resume_continues_from_the_saved_step(tmp_path):
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    run_dir = tmp_path / "run"
    proc = subprocess.Popen(
        [str(BIN / "drs-learn"), *TINY, "total_frames=2048", f"hydra.run.dir={run_dir}"],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        _wait_for_state(run_dir, 1024, proc)
        proc.send_signal(signal.SIGKILL)
        proc.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
    from drs_torchrl.apps.build import Run
    from drs_torchrl.runtime.checkpoint import find_training_state

    state_dir = find_training_state(run_dir)
    saved_frames = int((state_dir / "COMPLETE").read_text())
    payload = torch.load(state_dir / "trainer.pt", weights_only=True)
    assert payload["counters"]["frames"] == saved_frames

    # the restored trainer holds exactly what was saved
    cfg = OmegaConf.load(run_dir / "config.yaml")
    assert cfg.demos.stage_buffers == "auto"  # no demonstrations to file: a fresh run from this config passes too
    tr = Run(cfg, "learn", run_dir, resume=True)
    try:
        assert tr.frames == saved_frames and tr.updater.updates == payload["counters"]["updates"]
        assert len(tr.updater.replay) == saved_frames  # every collected transition
        assert tr.learner.stage_buffers.episodes_per_stage.tolist() == payload["learner"]["stage_buffer_episodes"]
        assert 0 < len(tr.learner.stage_buffers) <= saved_frames
        assert torch.equal(tr.learner.loss.recent_stages, payload["learner"]["disc_loss"]["recent_stages"])
        assert tr.updater.optimizers["critic"].state_dict()["state"][0]["step"] == payload["counters"]["updates"]
        assert torch.equal(tr.updater.loss.log_alpha.detach(), payload["loss"]["log_alpha"])
    finally:
        tr.close()

    p = subprocess.run(
        [str(BIN / "drs-learn"), f"resume={run_dir}"], env=env, capture_output=True, text=True, timeout=600
    )
    assert p.returncode == 0, p.stderr[-3000:]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["resumed_from"] == saved_frames and summary["frames"] >= 2048
    # the killed process counts up to its last saved state; what it did after that was redone
    assert [(g["from"], g["to"]) for g in summary["segments"]] == [(0, saved_frames), (saved_frames, summary["frames"])]
    steps = _steps(run_dir / "train.csv")
    assert steps == sorted(set(steps)), "duplicate or unordered log rows"
    assert all(b - a <= 256 + 64 for a, b in zip(steps, steps[1:])), f"gap in the log: {steps}"
    assert steps[-1] >= 2048
    assert (run_dir / ".hydra").is_dir() and list(run_dir.glob(".hydra-resume-*"))


@pytest.mark.sim
@pytest.mark.slow
def test_sigterm_saves_state_and_resume_finishes(tmp_path):
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    run_dir = tmp_path / "run"
    proc = subprocess.Popen(
        [str(BIN / "drs-learn"), *TINY, "total_frames=100000", f"hydra.run.dir={run_dir}"],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    _wait_for_state(run_dir, 512, proc)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(120)
    assert proc.returncode == 143, err[-3000:]  # 128 + SIGTERM, after saving
    assert f"resume={run_dir}" in err
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["interrupted"] is True
    assert int((run_dir / "checkpoints" / "state" / "COMPLETE").read_text()) == summary["frames"]
    assert (run_dir / "checkpoints" / "reward.pt").is_file() and (run_dir / "checkpoints" / "policy.pt").is_file()
    p = subprocess.run(
        [str(BIN / "drs-learn"), f"resume={run_dir}", f"total_frames={summary['frames'] + 256}"],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert p.returncode == 0, p.stderr[-3000:]
    s2 = json.loads((run_dir / "summary.json").read_text())
    assert s2["resumed_from"] == summary["frames"] and s2["frames"] >= summary["frames"] + 256
    # the run's history: the interrupted process up to its saved state, then the resumed one
    assert [(g["from"], g["to"]) for g in s2["segments"]] == [(0, summary["frames"]), (summary["frames"], s2["frames"])]
    assert all(g["wall_s"] > 0 for g in s2["segments"]) and s2["env_steps_per_s_overall"] > 0


def _digest(d: Path) -> dict:
    return {str(f.relative_to(d)): hashlib.sha256(f.read_bytes()).hexdigest() for f in d.rglob("*") if f.is_file()}


@pytest.mark.sim
@pytest.mark.slow
def test_reuse_resumes_and_bad_resumes_leave_the_run_untouched(tmp_path, cli):
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    run_dir = tmp_path / "reuse"
    args = [a for a in TINY if not a.startswith("reward.disc")]
    p = subprocess.run(
        [str(BIN / "drs-reuse"), *args, "reward=dense", "total_frames=512", f"hydra.run.dir={run_dir}"],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert p.returncode == 0, p.stderr[-3000:]
    before = _digest(run_dir)
    for bad, code, expect in [
        (["algo=sac_paper"], 2, "cannot switch config group 'algo'"),
        (["algo.no_such_key=1"], 2, "no_such_key"),  # Hydra refuses it when composing: one line, exit 2
        (["total_frames=-3"], 2, "total_frames must be > 0"),
    ]:
        got, err = cli("reuse", f"resume={run_dir}", *bad)  # the console script's app, in this process
        assert got == code and expect in err, err[-2000:]
    got, err = cli("learn", f"resume={run_dir}")
    assert got == 2 and "resume it with drs-reuse" in err
    assert _digest(run_dir) == before, "a failed resume changed or added files in the run directory"
    p = subprocess.run(
        [str(BIN / "drs-reuse"), f"resume={run_dir}", "total_frames=768"],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert p.returncode == 0, p.stderr[-3000:]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["resumed_from"] == 512 and summary["frames"] >= 768

    # a training state written before 0.1.0 (no algorithm recorded): refused in one line, the run left as it was
    state = run_dir / "checkpoints" / "state" / "trainer.pt"
    payload = torch.load(state, weights_only=True)
    del payload["algo"]
    torch.save(payload, state)
    before = _digest(run_dir)
    got, err = cli("reuse", f"resume={run_dir}", "total_frames=1024")
    assert got == 2 and "training state predates drs-torchrl 0.1.0" in err and len(err.strip().splitlines()) == 1, err
    assert _digest(run_dir) == before


def test_resume_errors_are_clear(tmp_path):
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    p = subprocess.run(
        [str(BIN / "drs-learn"), f"resume={tmp_path / 'nothing'}"], env=env, capture_output=True, text=True, timeout=120
    )
    assert p.returncode == 2 and "not a drs-torchrl run directory" in p.stderr


def test_a_config_written_before_0_1_0_is_refused_in_one_line(tmp_path):
    """A config.yaml without algo.updater (the code before 0.1.0, never released) is not guessed at: refused."""
    from drs_torchrl.apps.cli import ResumeError, resume_config

    OmegaConf.save(
        OmegaConf.create({"phase": "learn", "algo": {"name": "sac_cpu", "gamma": 0.8}}), tmp_path / "config.yaml"
    )
    with pytest.raises(ResumeError, match=r"predates drs-torchrl 0.1.0 \(no algo.updater\); start a new run"):
        resume_config(tmp_path, "learn", [])


def test_a_config_saved_by_0_1_0_resumes_with_its_settings_under_their_new_names(tmp_path):
    """0.1.0 saved the discriminator steps per RL update as reward.disc.updates_per_sac_update: a resume reads its
    value as algo.reward_updates_per_update (where the learner takes it from now), and an override of the old name
    is refused naming the new one."""
    from drs_torchrl.apps.cli import ResumeError, resume_config

    saved = {
        "phase": "learn",
        "algo": {
            "name": "sac_cpu",
            "reward_updates_per_update": 1,
            "updater": {"_target_": "drs_torchrl.updaters.sac.make_sac_updater"},
        },
        "reward": {"name": "drs", "disc": {"updates_per_sac_update": 2, "lr": 3e-4}},
    }
    OmegaConf.save(OmegaConf.create(saved), tmp_path / "config.yaml")
    cfg = resume_config(tmp_path, "learn", [])
    assert cfg.algo.reward_updates_per_update == 2 and "updates_per_sac_update" not in cfg.reward.disc
    assert (
        resume_config(tmp_path, "learn", ["algo.reward_updates_per_update=0.5"]).algo.reward_updates_per_update == 0.5
    )
    with pytest.raises(ResumeError, match="updates_per_sac_update is now algo.reward_updates_per_update"):
        resume_config(tmp_path, "learn", ["reward.disc.updates_per_sac_update=3"])


def test_resume_config_applies_value_overrides_and_new_variant_parameters(tmp_path):
    """``resume=RUN_DIR`` takes value overrides on the saved config; ``+`` may add a variant parameter
    (e.g. ``+env.variant_overrides.max_steps=150``), nothing else that the run's config lacks."""
    from drs_torchrl.apps.cli import ResumeError, resume_config

    OmegaConf.save(
        OmegaConf.create(
            {"phase": "learn", "total_frames": 100, "env": {"family": "turn_valve", "variant_overrides": {}}}
        ),
        tmp_path / "config.yaml",
    )
    cfg = resume_config(tmp_path, "learn", ["total_frames=200", "+env.variant_overrides.max_steps=150"])
    assert cfg.total_frames == 200 and cfg.env.variant_overrides.max_steps == 150 and cfg.resume == str(tmp_path)
    for bad in (["+env.nothing.x=1"], ["env.variant_overrides.max_steps=150"], ["typo_key=1"]):
        with pytest.raises(ResumeError, match="does not exist in the config"):
            resume_config(tmp_path, "learn", bad)
    with pytest.raises(ResumeError, match="resume it with drs-learn"):
        resume_config(tmp_path, "reuse", [])
    # what the saved weights and buffers were made with stays; the same value is no change
    OmegaConf.save(
        OmegaConf.create({"phase": "learn", "reward": {"hidden": [32], "disc": {"window": 100}}}),
        tmp_path / "config.yaml",
    )
    assert resume_config(tmp_path, "learn", ["reward.hidden=[32]"]).reward.hidden == [32]
    for bad in (["reward.hidden=[64]"], ["reward.disc.window=200"]):
        with pytest.raises(ResumeError, match=f"cannot change {bad[0].split('=')[0]} of a run being resumed"):
            resume_config(tmp_path, "learn", bad)
    # the family, the action space, the policy's inputs and the number of critics shape the saved state too
    OmegaConf.save(
        OmegaConf.create(
            {
                "phase": "learn",
                "env": {"family": "turn_valve", "control_mode": None},
                "algo": {"policy_in_keys": ["observation"], "loss": {"num_qvalue_nets": 2}},
            }
        ),
        tmp_path / "config.yaml",
    )
    for bad in (
        ["env.family=stack_cube"],
        ["env.control_mode=pd_joint_pos"],
        ["algo.policy_in_keys=[observation,stage_indicators]"],
        ["algo.loss.num_qvalue_nets=5"],
    ):
        with pytest.raises(ResumeError, match=f"cannot change {bad[0].split('=')[0]} of a run being resumed"):
            resume_config(tmp_path, "learn", bad)
    OmegaConf.save(
        OmegaConf.create(
            {"phase": "learn", "total_frames": 100, "env": {"family": "turn_valve", "variant_overrides": {}}}
        ),
        tmp_path / "config.yaml",
    )
    # a reuse run keeps its frozen reward: another reward file is refused, the same bytes at a new path are taken
    a, b, same = tmp_path / "a.pt", tmp_path / "b.pt", tmp_path / "moved" / "a.pt"
    a.write_bytes(b"reward a")
    b.write_bytes(b"reward b")
    same.parent.mkdir()
    same.write_bytes(b"reward a")
    OmegaConf.save(OmegaConf.create({"phase": "reuse", "reward": {"checkpoint": str(a)}}), tmp_path / "config.yaml")
    with pytest.raises(ResumeError, match="cannot change reward.checkpoint of a run being resumed to a different"):
        resume_config(tmp_path, "reuse", [f"reward.checkpoint={b}"])
    assert resume_config(tmp_path, "reuse", [f"reward.checkpoint={same}"]).reward.checkpoint == str(same)
    OmegaConf.save(
        OmegaConf.create(
            {"phase": "learn", "total_frames": 100, "env": {"family": "turn_valve", "variant_overrides": {}}}
        ),
        tmp_path / "config.yaml",
    )
    # a key added to the config since the run started (stop_at_success) is taken from this version's config
    newer = OmegaConf.create({"phase": "learn", "total_frames": 100, "stop_at_success": 0.8})
    assert resume_config(tmp_path, "learn", ["stop_at_success=0.8"], composed=newer).stop_at_success == 0.8
    with pytest.raises(ResumeError, match="does not exist in the config"):
        resume_config(tmp_path, "learn", ["typo_key=1"], composed=newer)


@pytest.mark.sim
@pytest.mark.slow
def test_stop_at_success_ends_phase_1_as_finished_and_a_resume_can_ask_for_it(tmp_path):
    """``stop_at_success``: once the training success over a full episode window reaches it, the run
    ends with its final evaluation and saves, finished (not interrupted), short of total_frames; a run
    started before the key existed takes it on resume. (Threshold 0 so that a tiny run reaches it.)"""
    from drs_torchrl.tools.study import run_state

    env = dict(os.environ, PYTHONWARNINGS="ignore")
    run_dir = tmp_path / "run"
    base = [*TINY, "logger.episode_window=4", "env.max_episode_steps=32"]
    p = subprocess.run(
        [str(BIN / "drs-learn"), *base, "total_frames=384", f"hydra.run.dir={run_dir}"],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert p.returncode == 0, p.stderr[-3000:]
    assert "stopped_at_success" not in json.loads((run_dir / "summary.json").read_text())
    cfg = OmegaConf.load(run_dir / "config.yaml")  # as a run saved before the key existed
    del cfg["stop_at_success"]
    OmegaConf.save(cfg, run_dir / "config.yaml")
    p = subprocess.run(
        [str(BIN / "drs-learn"), f"resume={run_dir}", "total_frames=100000", "stop_at_success=0.0"],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert p.returncode == 0, p.stderr[-3000:]
    s = json.loads((run_dir / "summary.json").read_text())
    assert (
        s["interrupted"] is False
        and s["stopped_at_success"]["threshold"] == 0.0
        and s["stopped_at_success"]["episodes"] == 4
    )
    assert 384 < s["frames"] <= 384 + 256 + 64, s["frames"]  # the first train-log row after the resume
    assert _steps(run_dir / "eval.csv")[-1] == s["frames"]  # the final evaluation ran
    assert (run_dir / "checkpoints" / "reward.pt").is_file()
    assert run_state(run_dir, 100000) == "finished"  # a study does not resume it to total_frames
    assert "stop_at_success=0 at" in p.stdout


@pytest.mark.sim
@pytest.mark.slow
def test_eval_stop_at_success_ends_a_reuse_run_as_finished_at_the_evaluation_that_reached_it(tmp_path):
    """``eval.stop_at_success``: a run ends (finished, saved) at the evaluation that completes the streak, short of
    total_frames, and a study does not resume it. (Threshold 0 so that the first evaluation reaches it.)"""
    from drs_torchrl.tools.study import run_state

    run_dir = tmp_path / "run"
    args = [
        *tiny(frames=2048, eval_every=256, disc_batch=None),
        "reward=dense",
        "eval.stop_at_success=0.0",
        "eval.stop_streak=2",
    ]
    p = subprocess.run(
        [str(BIN / "drs-reuse"), *args, f"hydra.run.dir={run_dir}"],
        env=dict(os.environ, PYTHONWARNINGS="ignore"),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert p.returncode == 0, p.stderr[-3000:]
    s = json.loads((run_dir / "summary.json").read_text())
    assert s["interrupted"] is False and s["stopped_at_eval_success"]["streak"] == 2
    assert _steps(run_dir / "eval.csv") == [256, 512] and s["frames"] == 512  # two evaluations, no third
    assert (run_dir / "checkpoints" / "policy.pt").is_file()
    assert run_state(run_dir, 2048) == "finished"
    assert "eval.stop_at_success=0 in 2 evaluation(s) in a row at 512 env steps" in p.stdout
