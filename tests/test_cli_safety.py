"""Nothing lost, nothing silently wrong (issue 16): a closed pipe, interrupts, an existing run
directory and a value of the wrong type, through the real console scripts on real ManiSkill."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = [pytest.mark.sim, pytest.mark.slow]

BIN = Path(sys.executable).parent
TINY = [
    "total_frames=640", "algo.learning_starts=256", "algo.batch_size=64", "algo.hidden=[32,32]",
    "reward.disc.batch_size=32", "logger.interval=256", "eval.interval=512", "eval.episodes=1",
    "checkpoint_interval=512", "logger.tensorboard=false",
]
LIBRARY_CHATTER = ("Requested to use render device", "No initial pose set", "Initialized LazyTensorStorage",
                   "init_random_frames")


def run(*args, cwd, **kw):
    return subprocess.run([str(BIN / "drs-learn"), *args], cwd=cwd, capture_output=True, text=True, timeout=600, **kw)


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    d = tmp_path_factory.mktemp("run")
    p = run(*TINY, "logger.progress_bar=false", f"hydra.run.dir={d}", cwd=d)
    assert p.returncode == 0, p.stderr[-3000:]
    return d, p


def test_console_shows_no_library_chatter_unless_asked(finished, tmp_path):
    _, p = finished
    out = p.stdout + p.stderr
    assert "learner precision" in out and "env steps" in out
    for msg in LIBRARY_CHATTER:
        assert msg not in out, msg
    p = run(*TINY, "total_frames=320", "logger.progress_bar=false", "logger.library_messages=true",
            f"hydra.run.dir={tmp_path / 'loud'}", cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-2000:]
    assert "Requested to use render device" in p.stdout + p.stderr


def test_a_new_run_is_refused_in_a_directory_that_holds_one(finished):
    d, _ = finished
    before = {f: f.read_bytes() for f in (d / "train.csv", d / "config.yaml", d / ".hydra" / "overrides.yaml")}
    p = run(*TINY, f"hydra.run.dir={d}", cwd=d)
    assert p.returncode == 2
    assert "already holds a run" in p.stderr and f"resume={d}" in p.stderr and "overwrite=true" in p.stderr
    assert "Traceback" not in p.stderr
    assert {f: f.read_bytes() for f in before} == before  # nothing of the old run was touched
    assert not list(d.glob(".hydra-new-*"))


def test_overwrite_true_replaces_the_run(finished, tmp_path):
    d, _ = finished
    target = tmp_path / "copy"
    subprocess.run(["cp", "-r", str(d), str(target)], check=True)
    p = run(*TINY, "total_frames=320", "overwrite=true", f"hydra.run.dir={target}", cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-2000:]
    rows = (target / "train.csv").read_text().splitlines()
    assert rows[-1].split(",")[0] == "320"  # only the new run's rows
    assert "total_frames=320" in (target / ".hydra" / "overrides.yaml").read_text()
    assert not list(target.glob(".hydra-new-*"))


@pytest.mark.parametrize("override,message", [
    ("total_frames=abc", "total_frames must be an integer, got 'abc'"),
    ("algo.gamma=high", "algo.gamma must be a number, got 'high'"),
    ("eval.episode_seed=first", "eval.episode_seed must be an integer or null, got 'first'"),
])
def test_a_value_of_the_wrong_type_is_one_line_and_the_fix(tmp_path, override, message):
    p = run(override, f"hydra.run.dir={tmp_path / 'r'}", cwd=tmp_path)
    assert p.returncode == 2
    assert message in p.stderr and "e.g." in p.stderr
    assert "Traceback" not in p.stderr
    assert not (tmp_path / "r" / "config.yaml").exists()


def _wait_for_progress(run_dir: Path, proc, timeout=300):
    t0 = time.time()
    while time.time() - t0 < timeout:
        if (run_dir / "train.csv").is_file() and len((run_dir / "train.csv").read_text().splitlines()) >= 2:
            return
        assert proc.poll() is None, "the run ended before it was interrupted"
        time.sleep(0.5)
    raise AssertionError("no progress")


@pytest.mark.parametrize("sig,code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_interrupted_run_saves_and_exits_non_zero_even_with_its_pipe_closed(tmp_path, sig, code):
    d = tmp_path / "r"
    args = [*TINY, "total_frames=200000", "logger.interval=128", "logger.progress_bar=false", f"hydra.run.dir={d}"]
    proc = subprocess.Popen([str(BIN / "drs-learn"), *args], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=dict(os.environ))
    if sig == signal.SIGINT:  # "drs-learn ... | tee log" and Ctrl-C: tee is gone before the run writes again
        proc.stdout.close()
        proc.stderr.close()
    _wait_for_progress(d, proc)
    proc.send_signal(sig)
    rc = proc.wait(timeout=300)
    assert rc == code
    state = d / "checkpoints" / "state" / "COMPLETE"
    assert state.is_file() and int(state.read_text()) >= 128
    assert (d / "checkpoints" / "reward.pt").is_file() and (d / "checkpoints" / "policy.pt").is_file()
    if sig == signal.SIGTERM:
        err = proc.stderr.read().decode()
        assert f"resume={d}" in err
    # and it resumes from there
    p = run(f"resume={d}", "total_frames=" + str(int(state.read_text()) + 64), cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-2000:]


def test_drs_demos_console_shows_no_library_chatter_unless_asked(tmp_path):
    """``drs-demos`` (the motion planner through ManiSkill) filters the same chatter as ``drs-learn``."""
    cmd = [str(BIN / "drs-demos"), "--family", "pick_cube", "--num", "1"]
    p = subprocess.run([*cmd, "--out", str(tmp_path / "quiet.demos")], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    out = p.stdout + p.stderr
    assert "1 demonstrations" in out
    for msg in LIBRARY_CHATTER:
        assert msg not in out, msg
    env = {**os.environ, "DRS_LIBRARY_MESSAGES": "1"}
    p = subprocess.run([*cmd, "--out", str(tmp_path / "loud.demos")], cwd=tmp_path, capture_output=True, text=True,
                       timeout=600, env=env)
    assert p.returncode == 0, p.stderr[-3000:]
    assert "Requested to use render device" in p.stdout + p.stderr
