"""One writer per run directory, a full disk and the console's one-line errors (issue 48), without the simulator.

The full-disk cases write on a real 1 MB tmpfs mounted in a private mount namespace (``unshare``)."""

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
from collections import Counter
from pathlib import Path

import pytest

from drs_torchrl.runtime.console import UserError, console_script, library_prints, one_line, report_failure
from drs_torchrl.runtime.rundir import LOCK_NAME, check_writable, lock_run_dir, unlock_run_dir

REPO = Path(__file__).resolve().parents[1]
LOCK_IN_CHILD = (
    "import sys; from drs_torchrl.runtime.rundir import lock_run_dir; lock_run_dir(sys.argv[1]); print('locked')"
)


def test_a_second_process_is_refused_naming_the_holder_until_it_lets_go(tmp_path):
    run = tmp_path / "run"
    lock_run_dir(run)
    try:
        p = subprocess.run([sys.executable, "-c", LOCK_IN_CHILD, str(run)], capture_output=True, text=True, timeout=120)
        assert p.returncode != 0
        assert "RunDirBusyError" in p.stderr and f"pid {os.getpid()}" in p.stderr and str(run) in p.stderr
        assert lock_run_dir(run) == run.resolve()  # the holder may ask again
    finally:
        unlock_run_dir(run)
    assert not (run / LOCK_NAME).exists()  # the lock file lives while it is held
    p = subprocess.run([sys.executable, "-c", LOCK_IN_CHILD, str(run)], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0 and "locked" in p.stdout
    assert list(run.iterdir()) == []  # released at the child's exit


def test_the_lock_of_a_dead_process_does_not_block(tmp_path):
    run = tmp_path / "run"
    killed = subprocess.run(
        [sys.executable, "-c", LOCK_IN_CHILD + "; import os; os.kill(os.getpid(), 9)", str(run)], timeout=120
    )
    assert killed.returncode == -signal.SIGKILL
    assert (run / LOCK_NAME).read_text().strip()  # its pid is still written there
    lock_run_dir(run)
    assert (run / LOCK_NAME).read_text().strip() == str(os.getpid())
    unlock_run_dir(run)
    assert not (run / LOCK_NAME).exists()


def test_a_failed_start_removes_a_directory_that_holds_only_its_lock(tmp_path):
    run = tmp_path / "made"
    lock_run_dir(run)
    unlock_run_dir(run, remove_if_empty=True)
    assert not run.exists()
    kept = tmp_path / "kept"
    lock_run_dir(kept)
    (kept / "train.csv").write_text("step\n")
    unlock_run_dir(kept, remove_if_empty=True)
    assert [p.name for p in kept.iterdir()] == ["train.csv"]


def test_the_lock_file_is_not_a_run_file(tmp_path):
    """A directory holding only the lock is fresh for drs-learn and drs-quickstart, and drs-study --report
    copies only named files."""
    from drs_torchrl.tools.quickstart import Job, prepare_out
    from drs_torchrl.tools.study import load_study, report
    from drs_torchrl.apps.cli import check_fresh_run_dir

    fresh = tmp_path / "fresh"
    lock_run_dir(fresh)
    check_fresh_run_dir(fresh, "learn", overwrite=False)  # no ExistingRunError
    assert prepare_out(fresh, [Job("learn", "t", [])], overwrite=False) == []
    unlock_run_dir(fresh)

    root = tmp_path / "study"
    (root / "a").mkdir(parents=True)
    for name, text in {
        "train.csv": "step,frames\n1,1\n",
        "config.yaml": "total_frames: 10\n",
        LOCK_NAME: "123\n",
    }.items():
        (root / "a" / name).write_text(text)
    study = tmp_path / "s.yaml"
    study.write_text(f"root: {root}\napp: learn\nruns:\n  - {{name: a, args: [seed=0]}}\n")
    _, runs = load_study(study)
    report(root, runs, tmp_path / "out", study)
    copied = {p.name for p in (tmp_path / "out" / "run_files" / "a").iterdir()}
    assert copied == {"train.csv", "config.yaml"}


def test_a_run_replaced_with_overwrite_is_set_aside_until_the_new_one_has_started(tmp_path):
    """overwrite=true moves the old run's files aside: a new run that fails to start (a check after the directory
    was cleared) gets them back, byte for byte, over what it wrote; one that starts drops them."""
    from drs_torchrl.apps.cli import RUN_MARKERS, ExistingRunError, check_fresh_run_dir, replaced

    d = tmp_path / "run"
    (d / "checkpoints").mkdir(parents=True)
    old = {"config.yaml": "old config\n", "train.csv": "step\n1\n", "checkpoints/reward.pt": "weights", "tb/ev": "x"}
    for name, text in old.items():
        (d / name).parent.mkdir(parents=True, exist_ok=True)
        (d / name).write_text(text)
    with pytest.raises(ExistingRunError, match="already holds a run"):
        check_fresh_run_dir(d, "learn", overwrite=False)
    aside = check_fresh_run_dir(d, "learn", overwrite=True)
    assert aside and not any((d / m).exists() for m in (*RUN_MARKERS, "tb"))
    (d / "config.yaml").write_text("new config\n")  # what the refused new run wrote before failing
    (d / "checkpoints").mkdir()
    aside.restore()
    assert {n: (d / n).read_text() for n in old} == old and not list(d.glob(".replaced-*"))
    # a new run that starts: the old files go for good
    aside = check_fresh_run_dir(d, "learn", overwrite=True)
    (d / "config.yaml").write_text("new config\n")
    replaced(d, aside)
    assert (d / "config.yaml").read_text() == "new config\n" and not (d / "train.csv").exists()
    assert not list(d.glob(".replaced-*"))
    assert not check_fresh_run_dir(tmp_path / "empty", "learn", overwrite=True)  # nothing to replace


def test_an_output_path_that_cannot_be_written_is_named_at_once(tmp_path):
    a_file = tmp_path / "f"
    a_file.write_text("x")
    with pytest.raises(UserError, match=r"--video .*/f is a file, not a folder"):
        check_writable(a_file, "--video", folder=True)
    with pytest.raises(UserError, match=r"--out .* is a folder; give a file name"):
        check_writable(tmp_path, "--out")
    with pytest.raises(UserError, match=r"cannot be made: .*/f is a file, not a folder"):
        check_writable(a_file / "sub" / "x.json", "--out")
    assert check_writable(tmp_path / "new" / "x.json", "--out") == tmp_path / "new" / "x.json"


def _on_small_filesystem(tmp_path: Path, code: str, size: str = "1m") -> dict:
    """Run ``code`` (which prints one JSON line) in a private mount namespace where ``tmp_path/small`` is a
    tmpfs of ``size``; skips (saying why) where no namespace or tmpfs can be made."""
    small = tmp_path / "small"
    small.mkdir()
    ns = ["unshare", "--mount"] if os.geteuid() == 0 else ["unshare", "--user", "--map-root-user", "--mount"]
    script = f'mount -t tmpfs -o size={size} tmpfs {small} || exit 99; exec {sys.executable} -c "$0" {small}'
    if shutil.which("unshare") is None:
        pytest.skip("no unshare(1): cannot mount a small filesystem to fill")
    p = subprocess.run([*ns, "sh", "-c", script, textwrap.dedent(code)], capture_output=True, text=True, timeout=300)
    if p.returncode == 99 or (p.returncode != 0 and "unshare:" in p.stderr):
        pytest.skip(f"cannot mount a small filesystem here: {p.stderr.strip()[:200]}")
    assert p.returncode == 0, p.stderr[-3000:]
    return json.loads(p.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_a_full_disk_is_one_error_and_leaves_no_partial_files(tmp_path):
    """On a 1 MB filesystem: a 2 MB buffer snapshot is refused before its memory map could fault (SIGBUS),
    a checkpoint over an older one keeps the older one, and a text write that fills the disk is reported;
    no temporary file is left."""
    out = _on_small_filesystem(
        tmp_path,
        """
        import json, os, sys, torch
        from pathlib import Path
        from tensordict import TensorDict
        from torchrl.data import LazyTensorStorage, ReplayBuffer
        from drs_torchrl.data.persistence import dump_buffer
        from drs_torchrl.runtime.rundir import DiskFullError
        from drs_torchrl.runtime.checkpoint import atomic_torch_save, atomic_write_text

        d, res = Path(sys.argv[1]), {}
        rb = ReplayBuffer(storage=LazyTensorStorage(1000))
        rb.extend(TensorDict({"observation": torch.ones(1000, 512)}, [1000]))  # 2 MB
        try:
            dump_buffer(rb, d / "state" / "replay")
        except DiskFullError as exc:
            res["buffer"] = str(exc)
        atomic_torch_save({"w": torch.ones(10)}, d / "policy.pt")
        try:
            atomic_torch_save({"w": torch.ones(300_000)}, d / "policy.pt")
        except DiskFullError as exc:
            res["checkpoint"] = str(exc)
        res["old_checkpoint"] = torch.load(d / "policy.pt")["w"].numel()
        try:
            atomic_write_text(d / "summary.json", "x" * 2_000_000)
        except DiskFullError as exc:
            res["text"] = str(exc)
        res["files"] = sorted(str(p.relative_to(d)) for p in d.rglob("*"))
        print(json.dumps(res))
    """,
    )
    assert "not enough space to write the buffer snapshot" in out["buffer"] and "/state/replay" in out["buffer"]
    assert "MiB are free; free some space there" in out["buffer"]
    assert "the disk filled while writing the file" in out["checkpoint"] and "policy.pt" in out["checkpoint"]
    assert out["old_checkpoint"] == 10
    assert "summary.json" in out["text"] and "MiB free" in out["text"]
    assert out["files"] == ["policy.pt"]


def test_a_user_error_is_one_line_and_a_bug_keeps_its_traceback(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("DRS_LOG_DIR", str(tmp_path / "logs"))
    assert report_failure("drs-x", UserError("bad value 3; use 4")) == 2
    assert capsys.readouterr().err == "drs-x: error: bad value 3; use 4\n"
    assert report_failure("drs-x", IsADirectoryError(21, "Is a directory", "/some/dir")) == 2
    assert capsys.readouterr().err == "drs-x: error: /some/dir: Is a directory; it is a folder: give a file name\n"

    def buggy():
        return {}["missing"]

    try:
        buggy()
    except KeyError as exc:
        assert report_failure("drs-x", exc) == 1
    err = capsys.readouterr().err
    assert "Traceback" in err and "buggy" in err
    log = err.strip().splitlines()[-1].split("kept in ")[1].split(":")[0]
    assert "internal error (KeyError)" in err and "buggy" in Path(log).read_text()


def test_every_failure_of_a_wrapped_entry_function_exits_with_its_code(capsys, monkeypatch, tmp_path):
    monkeypatch.setenv("DRS_LOG_DIR", str(tmp_path))

    monkeypatch.setenv("HYDRA_FULL_ERROR", "0")
    seen = []

    @console_script("drs-x", quiet=False)
    def main(what):
        seen.append(os.environ["HYDRA_FULL_ERROR"])  # Hydra re-raises into the wrapper instead of printing
        raise what

    for exc, code in [(UserError("no"), 2), (KeyboardInterrupt(), 130), (RuntimeError("bug"), 1), (SystemExit(3), 3)]:
        with pytest.raises(SystemExit) as e:
            main(exc)
        assert e.value.code == code
    assert seen == ["1"] * 4 and os.environ["HYDRA_FULL_ERROR"] == "0"
    err = capsys.readouterr().err
    assert "drs-x: error: no\n" in err and "drs-x: interrupted" in err and "internal error (RuntimeError)" in err


def test_hydra_messages_become_one_line():
    text = (
        "In 'learn': Could not find 'reward/vice'\n\nAvailable options in 'reward':\n\tdense\n\tdrs\n"
        "Config search path:\n\tprovider=hydra, path=pkg://hydra.conf\n"
    )
    assert one_line(text) == "In 'learn': Could not find 'reward/vice'; Available options in 'reward': dense, drs"


def test_library_prints_are_counted_not_shown(capsys, monkeypatch):
    monkeypatch.delenv("DRS_LIBRARY_MESSAGES", raising=False)
    said = Counter()
    with library_prints(said):
        print("screw plan failed")
        print("screw plan failed")
    assert said == Counter({"screw plan failed": 2}) and capsys.readouterr().out == ""
    monkeypatch.setenv("DRS_LIBRARY_MESSAGES", "1")
    with library_prints(said):
        print("screw plan failed")
    assert "screw plan failed" in capsys.readouterr().out


def test_saved_files_reach_the_disk_before_anything_vouches_for_them(tmp_path, monkeypatch):
    """A machine crash (power, kernel) loses what is only in the page cache: the training state is flushed before
    its COMPLETE marker is written, the marker before the swap, the swap before the fallback state is deleted."""
    import drs_torchrl.runtime.checkpoint as ck
    from drs_torchrl.runtime.rundir import fsync_tree

    (tmp_path / "tree" / "sub").mkdir(parents=True)
    (tmp_path / "tree" / "sub" / "f").write_text("x")
    fsync_tree(tmp_path / "tree")  # real files and folders: no error

    events = []
    real_rename = Path.rename

    def listing(p):
        p = Path(p)
        return sorted(x.name for x in p.iterdir()) if p.is_dir() else p.name

    monkeypatch.setattr(ck, "fsync_tree", lambda p: events.append(("flush", listing(p))))
    monkeypatch.setattr(ck, "fsync_path", lambda p: events.append(("fsync", Path(p).name)))
    monkeypatch.setattr(
        Path, "rename", lambda self, to: (events.append(("rename", self.name, Path(to).name)), real_rename(self, to))[1]
    )
    checkpointer = ck.Checkpointer(tmp_path / "run")
    checkpointer._write_state({"counters": {"frames": 1}})
    events.clear()
    checkpointer._write_state({"counters": {"frames": 2}})
    tmp = f"state.tmp-{os.getpid()}"
    assert events == [
        ("flush", ["trainer.pt"]),
        ("fsync", "COMPLETE"),
        ("fsync", tmp),
        ("rename", "state", "state.old"),
        ("rename", tmp, "state"),
        ("fsync", "checkpoints"),
    ]
    assert (tmp_path / "run" / "checkpoints" / "state" / "COMPLETE").read_text() == "2"
    assert not (tmp_path / "run" / "checkpoints" / "state.old").exists()


@pytest.mark.parametrize("app", ["apps.evaluate", "tools.reporting", "tools.comparison"])
def test_a_maze_run_given_to_a_maniskill_command_is_named_as_one(app, tmp_path, capsys):
    """drs-eval had called a drs-maze run's config "damaged", drs-plot failed with 'reward_min', drs-compare tabled it
    beside ManiSkill runs as "no eval yet"."""
    import importlib

    maze = tmp_path / "learn"
    shutil.copytree(REPO / "results/quickstart/seed1/learn", maze)  # a committed drs-quickstart run
    before = {p.name: p.read_bytes() for p in maze.iterdir() if p.is_file()}
    main = importlib.import_module(f"drs_torchrl.{app}").main
    try:
        code = main([str(maze)])
    except SystemExit as e:  # the console wrapper's exit for a UserError
        code = e.code
    assert code == 2
    err = capsys.readouterr().err
    assert f"{maze} is a drs-maze run (the maze family's app, conf/maze.yaml), not a drs-learn/drs-reuse run" in err
    assert f"drs-maze phase=report report.root={tmp_path}" in err and err.count("\n") == 1
    assert {p.name: p.read_bytes() for p in maze.iterdir() if p.is_file()} == before
