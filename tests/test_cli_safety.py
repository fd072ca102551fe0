"""Nothing lost, nothing silently wrong (issue 16): a closed pipe, interrupts, an existing run
directory and a value of the wrong type, through the real console scripts on real ManiSkill."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from budgets import small


BIN = Path(sys.executable).parent
TINY = small(eval_every=512, checkpoint_every=512, progress_bar=None, background=True)
LIBRARY_CHATTER = (
    "Requested to use render device",
    "No initial pose set",
    "Initialized LazyTensorStorage",
    "init_random_frames",
    "screw plan failed",
)


def run(*args, cwd, **kw):
    return subprocess.run([str(BIN / "drs-learn"), *args], cwd=cwd, capture_output=True, text=True, timeout=600, **kw)


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    d = tmp_path_factory.mktemp("run")
    p = run(*TINY, "logger.progress_bar=false", f"hydra.run.dir={d}", cwd=d)
    assert p.returncode == 0, p.stderr[-3000:]
    return d, p


@pytest.mark.sim
@pytest.mark.slow
def test_console_shows_no_library_chatter_unless_asked(finished, tmp_path):
    _, p = finished
    out = p.stdout + p.stderr
    assert "learner precision" in out and "env steps" in out
    for msg in LIBRARY_CHATTER:
        assert msg not in out, msg
    # logger.library_messages=true shows them: test_overwrite_true_replaces_the_run's run asks for them


@pytest.mark.sim
@pytest.mark.slow
def test_a_new_run_is_refused_in_a_directory_that_holds_one(finished, cli):
    """(In this process; the console script's one line for the same refusal: results/bad_inputs/, its table test.)"""
    d, _ = finished
    before = {f: f.read_bytes() for f in (d / "train.csv", d / "config.yaml", d / ".hydra" / "overrides.yaml")}
    code, err = cli("learn", *TINY, f"hydra.run.dir={d}")
    assert code == 2
    assert "already holds a run" in err and f"resume={d}" in err and "overwrite=true" in err
    assert "Traceback" not in err
    assert {f: f.read_bytes() for f in before} == before  # nothing of the old run was touched
    assert not list(d.glob(".hydra-new-*"))


@pytest.mark.sim
@pytest.mark.slow
def test_overwrite_true_replaces_the_run(finished, tmp_path):
    d, _ = finished
    target = tmp_path / "copy"
    subprocess.run(["cp", "-r", str(d), str(target)], check=True)
    p = run(
        *TINY,
        "total_frames=320",
        "overwrite=true",
        "logger.library_messages=true",
        f"hydra.run.dir={target}",
        cwd=tmp_path,
    )
    assert p.returncode == 0, p.stderr[-2000:]
    assert "Requested to use render device" in p.stdout + p.stderr  # the libraries' notices, asked for
    rows = (target / "train.csv").read_text().splitlines()
    assert rows[-1].split(",")[0] == "320"  # only the new run's rows
    assert "total_frames=320" in (target / ".hydra" / "overrides.yaml").read_text()
    assert not list(target.glob(".hydra-new-*"))


def test_a_value_of_the_wrong_type_is_one_line_and_the_fix(cli, tmp_path):
    """(In this process: a refusal before anything is built; the console script's: results/bad_inputs/. Every other
    setting's type and range message: test_schema.py.)"""
    code, err = cli("learn", "total_frames=abc", f"hydra.run.dir={tmp_path / 'r'}")
    assert code == 2
    assert err.strip() == "drs-learn: error: total_frames must be an integer, got 'abc' (str); e.g. total_frames=200000"
    assert not (tmp_path / "r").exists()  # no folder left holding only Hydra's record


def _wait_for_progress(run_dir: Path, proc, timeout=300):
    t0 = time.time()
    while time.time() - t0 < timeout:
        if (run_dir / "train.csv").is_file() and len((run_dir / "train.csv").read_text().splitlines()) >= 2:
            return
        assert proc.poll() is None, "the run ended before it was interrupted"
        time.sleep(0.5)
    raise AssertionError("no progress")


@pytest.mark.sim
@pytest.mark.slow
def test_ctrl_c_with_its_pipe_closed_saves_and_exits_130(tmp_path):
    """``drs-learn ... | tee log`` and Ctrl-C: tee is gone before the run writes again; the run still saves its state
    and exits 130. (SIGTERM, exit 143, with the pipe open: test_resume.py.)"""
    d = tmp_path / "r"
    args = [*TINY, "total_frames=200000", "logger.interval=128", "logger.progress_bar=false", f"hydra.run.dir={d}"]
    proc = subprocess.Popen(
        [str(BIN / "drs-learn"), *args],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=dict(os.environ),
    )
    proc.stdout.close()
    proc.stderr.close()
    _wait_for_progress(d, proc)
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=300) == 130
    state = d / "checkpoints" / "state" / "COMPLETE"
    assert state.is_file() and int(state.read_text()) >= 128
    assert (d / "checkpoints" / "reward.pt").is_file() and (d / "checkpoints" / "policy.pt").is_file()
    # and it resumes from there
    p = run(f"resume={d}", "total_frames=" + str(int(state.read_text()) + 64), cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-2000:]


@pytest.mark.sim
@pytest.mark.slow
def test_drs_demos_console_shows_no_library_chatter_unless_asked(tmp_path):
    """``drs-demos`` (the motion planner through ManiSkill) filters the same chatter as ``drs-learn``."""
    cmd = [str(BIN / "drs-demos"), "--family", "pick_cube", "--num", "1"]
    p = subprocess.run(
        [*cmd, "--out", str(tmp_path / "quiet.demos")], cwd=tmp_path, capture_output=True, text=True, timeout=600
    )
    assert p.returncode == 0, p.stderr[-3000:]
    out = p.stdout + p.stderr
    assert "1 demonstrations" in out
    for msg in LIBRARY_CHATTER:
        assert msg not in out, msg
    # DRS_LIBRARY_MESSAGES=1 shows them (the console scripts' shared switch): test_drs_bench_collector_workers_filter_library_messages


# ---------------------------------------------------------------------------------------------- issue 48
@pytest.mark.sim
@pytest.mark.slow
def test_a_full_disk_while_saving_is_one_line_and_the_last_state_resumes(tmp_path):
    """drs-learn on a 3 MB filesystem (tmpfs in a private mount namespace): the state at 2048 env steps fits,
    the checkpoint at 3072 does not. Without the space check the memory-mapped buffers died of SIGBUS (135)."""
    small, out = tmp_path / "small", tmp_path / "out"
    small.mkdir()
    out.mkdir()
    args = [
        "total_frames=4096",
        "algo.learning_starts=4096",
        "algo.batch_size=32",
        "algo.hidden=[32,32]",
        "eval.episodes=0",
        "checkpoint_interval=1024",
        "logger.interval=512",
        "stop_at_success=null",
        "logger.progress_bar=false",
        "logger.tensorboard=false",
        f"hydra.run.dir={small / 'run'}",
    ]
    ns = ["unshare", "--mount"] if os.geteuid() == 0 else ["unshare", "--user", "--map-root-user", "--mount"]
    script = (
        f"mount -t tmpfs -o size=3m tmpfs {small} || exit 99; {BIN / 'drs-learn'} {' '.join(args)}; "
        f"rc=$?; cp -a {small / 'run'} {out}/; exit $rc"
    )
    p = subprocess.run([*ns, "sh", "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    if p.returncode == 99 or "unshare:" in p.stderr:
        pytest.skip(f"cannot mount a small filesystem here: {p.stderr.strip()[:200]}")
    assert p.returncode == 2, p.stderr[-3000:]
    errors = [ln for ln in p.stderr.splitlines() if "error" in ln.lower()]
    assert len(errors) == 1 and "Traceback" not in p.stderr, p.stderr[-3000:]
    assert (
        f"{small / 'run' / 'checkpoints'}: it needs about" in errors[0] and "MiB are free; free some space" in errors[0]
    )
    assert f"the training state at 2048 env steps is kept: continue with drs-learn resume={small / 'run'}" in errors[0]
    run_dir = out / "run"
    assert (run_dir / "checkpoints" / "state" / "COMPLETE").read_text() == "2048"
    assert (
        not list((run_dir / "checkpoints").glob("state.tmp-*")) and not (run_dir / "checkpoints" / "state.old").exists()
    )
    assert not (run_dir / "summary.json").exists()  # the run did not finish, and says nothing else
    p = subprocess.run(
        [str(BIN / "drs-learn"), f"resume={run_dir}", "total_frames=2304"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )  # the state resumes (here, with room)
    assert p.returncode == 0, p.stderr[-2000:]
    assert "2304 env steps" in p.stdout


def test_resume_of_a_damaged_config_names_the_file_and_its_copy(cli, tmp_path):
    d = tmp_path / "r"
    (d / ".hydra").mkdir(parents=True)
    (d / ".hydra" / "config.yaml").write_text("seed: 0\n")
    (d / "config.yaml").write_text("phase: learn\nenv: [unclosed\n")
    before = sorted(p.name for p in d.iterdir())
    code, err = cli("learn", f"resume={d}")
    assert code == 2
    assert f"cannot resume: {d / 'config.yaml'} is damaged (not valid YAML at line 3)" in err
    assert str(d / ".hydra" / "config.yaml") in err and "Traceback" not in err
    assert sorted(p.name for p in d.iterdir()) == before  # as it was (the lock file went with the lock)
    (d / "config.yaml").write_text("- a list\n")
    code, err = cli("learn", f"resume={d}")
    assert code == 2 and "is damaged: it lacks phase" in err


def test_an_env_id_gymnasium_does_not_know_is_one_line(cli, tmp_path):
    code, err = cli(
        "learn", "env=custom", "env.family=mine", "env.env_id=PushCub-v1", f"hydra.run.dir={tmp_path / 'r'}"
    )
    assert code == 2 and "Traceback" not in err
    assert "drs-learn: error: env.env_id=PushCub-v1: gymnasium: Environment `PushCub` doesn't exist" in err
    assert "PushCube" in err
    assert not (tmp_path / "r" / "config.yaml").exists()


def test_drs_eval_refuses_a_video_path_that_is_a_file_before_any_episode(tmp_path, capsys):
    from drs_torchrl.apps.evaluate import main

    (tmp_path / "v").write_text("a file")
    with pytest.raises(SystemExit) as e:
        main([str(tmp_path), "--video", str(tmp_path / "v")])
    assert e.value.code == 2
    assert (
        capsys.readouterr().err
        == f"drs-eval: error: --video {tmp_path / 'v'} is a file, not a folder; give a folder (it is made if missing)\n"
    )


def test_drs_demos_never_replaces_a_folder_that_is_not_demonstrations(tmp_path, capsys):
    from drs_torchrl.tools.demos import main

    (tmp_path / "mine.txt").write_text("keep me")
    assert main(["--num", "1", "--out", str(tmp_path)]) == 2
    assert "is a folder that does not hold demonstrations" in capsys.readouterr().err
    assert (tmp_path / "mine.txt").read_text() == "keep me"


def test_drs_demos_replaces_demonstrations_only_when_told(tmp_path, capsys):
    """An earlier recording at --out is refused before any recording (pass --force); the default --out never
    replaces one: it takes the next free name."""
    from drs_torchrl.tools.demos import main
    from drs_torchrl.demos.store import free_demos_path

    kept = tmp_path / "pc.demos"
    kept.mkdir()
    (kept / "meta.json").write_text('{"episodes": 1000}')
    assert main(["--num", "1", "--out", str(kept)]) == 2
    assert "already holds demonstrations; pass --force" in capsys.readouterr().err
    assert (kept / "meta.json").read_text() == '{"episodes": 1000}'
    assert free_demos_path(kept) == tmp_path / "pc-2.demos"
    (tmp_path / "pc-2.demos").mkdir()
    assert free_demos_path(kept) == tmp_path / "pc-3.demos"
    assert free_demos_path(tmp_path / "new.demos") == tmp_path / "new.demos"


@pytest.mark.sim
@pytest.mark.slow
def test_drs_bench_collector_workers_filter_library_messages(tmp_path):
    """The background collector's worker process applies the console filter (ManiSkill's render-device and
    initial-pose warnings came from there); DRS_LIBRARY_MESSAGES=1 shows them again."""
    code = (
        "import sys; from drs_torchrl.runtime.console import quiet_libraries, library_messages_requested\n"
        "library_messages_requested() or quiet_libraries()\n"
        "from drs_torchrl.tools.bench import bench_collect; from drs_torchrl.tasks import get_family\n"
        "print(bench_collect(get_family('pick_cube'), 64, 'background') > 0)"
    )
    env = {
        k: v for k, v in os.environ.items() if k not in ("RL_WARNINGS", "DRS_LIBRARY_MESSAGES", "DRS_QUIET_LIBRARIES")
    }
    quiet = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path, timeout=600
    )
    assert quiet.returncode == 0 and "True" in quiet.stdout, quiet.stderr[-3000:]
    loud = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=600,
        env={**env, "DRS_LIBRARY_MESSAGES": "1"},
    )
    assert loud.returncode == 0, loud.stderr[-3000:]
    assert "Requested to use render device" in loud.stdout + loud.stderr
    for msg in LIBRARY_CHATTER:
        assert msg not in quiet.stdout + quiet.stderr, msg


def test_a_keyerror_while_training_is_a_bug_not_a_setting(tmp_path):
    """While the run is built, the config layer's KeyError/ValueError name a bad setting (one line, exit 2); once
    the first env step is taken, the same exception types come from a bug and keep their traceback."""
    from omegaconf import OmegaConf

    from drs_torchrl.apps.cli import _user_message

    cfg = OmegaConf.create({})
    assert _user_message(KeyError("unknown reward 'x'"), cfg, "learn", tmp_path) == "unknown reward 'x'"
    assert _user_message(ValueError("bad shape"), cfg, "learn", tmp_path, training=True) is None
    assert _user_message(KeyError(("next", "stage")), cfg, "learn", tmp_path, training=True) is None


@pytest.mark.parametrize(
    "script,args",
    [
        ("drs-learn", ["hydra.run.dir= "]),  # (drs-reuse: the same code)
        ("drs-maze", ["hydra.run.dir="]),
        ("drs-quickstart", ["out="]),
    ],
)
def test_an_empty_run_directory_is_refused_and_nothing_lands_in_the_working_directory(
    cli, monkeypatch, tmp_path, script, args
):
    """``hydra.run.dir=$RUN`` with RUN unset: Hydra made the working directory the run's (a run's files, or a
    quickstart's four runs, among the user's own). (In this process, in a working directory of the user's.)"""
    (tmp_path / "mine.txt").write_text("the user's file\n")
    monkeypatch.chdir(tmp_path)
    code, err = cli(script.removeprefix("drs-"), *args)
    assert code == 2, err[-2000:]
    assert err.strip().splitlines()[-1].startswith(f"{script}: error: ") and "is empty" in err
    assert sorted(f.name for f in tmp_path.iterdir()) == ["mine.txt"]
