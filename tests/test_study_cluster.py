"""drs-study --executor submitit-local | slurm: runs as submitit jobs, followed by a driver that can be stopped and
started again, dead jobs resubmitted with resume=, the cluster: section of a study file (docs/cluster.md)."""

import json
import os
import pickle
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from drs_torchrl.tools import study_cluster as sc
from drs_torchrl.tools.study import StudyError, load_cluster, load_study, main, run_state
from budgets import tiny

BIN = Path(sys.executable).parent


@pytest.fixture(autouse=True)
def fresh_slurm_answers():
    """Job ids repeat from test to test (fake and real clusters count from 1): no state cached across tests."""
    sc._SLURM_SEEN.clear()
    sc._has_sacct.cache_clear()
    yield
    sc._SLURM_SEEN.clear()
    sc._has_sacct.cache_clear()


def write(tmp_path, spec) -> Path:
    f = tmp_path / "study.yaml"
    f.write_text(yaml.safe_dump(spec, sort_keys=False))
    return f


# --- the cluster: section -----------------------------------------------------------------------------------------


def test_the_cluster_section_sets_the_jobs_resources_and_submitit_gets_them_per_cluster(tmp_path):
    f = write(
        tmp_path,
        {
            "root": "r",
            "runs": [{"name": "a"}],
            "cluster": {
                "partition": "gpu",
                "time_min": 240,
                "cpus_per_task": 4,
                "mem_gb": 16,
                "gpus": 1,
                "max_jobs": 8,
                "max_resubmits": 2,
                "signal_delay_s": 120,
                "setup": ["module load cuda"],
                "slurm_additional": {"account": "rl", "qos": 2},
            },
        },
    )
    c = load_cluster(f)
    assert (c.partition, c.time_min, c.cpus_per_task, c.mem_gb, c.gpus, c.max_jobs, c.max_resubmits) == (
        "gpu",
        240,
        4,
        16,
        1,
        8,
        2,
    )
    assert c.executor_parameters("slurm") == {
        "timeout_min": 240,
        "gpus_per_node": 1,
        "cpus_per_task": 4,
        "mem_gb": 16,
        "slurm_partition": "gpu",
        "slurm_signal_delay_s": 120,
        "slurm_setup": ["module load cuda"],
        "slurm_additional_parameters": {"account": "rl", "qos": "2"},
    }
    # one machine: the time limit and the GPUs only (Slurm's partition, memory, CPUs mean nothing there)
    assert c.executor_parameters("submitit-local") == {"timeout_min": 240, "gpus_per_node": 1}
    default = load_cluster(write(tmp_path, {"root": "r", "runs": [{"name": "a"}]}))
    assert default.executor_parameters("slurm") == {"timeout_min": 1440} and default.max_resubmits == 3


@pytest.mark.parametrize(
    "cluster,message",
    [
        ({"partiton": "x"}, "cluster: unknown keys \\['partiton'\\]"),
        ("gpu", "cluster: a mapping of partition"),
        ({"time_min": "2h"}, "time_min must be a whole number >= 1, got '2h'"),
        ({"time_min": 0}, "time_min must be a whole number >= 1"),
        ({"gpus": -1}, "gpus must be a whole number >= 0"),
        ({"cpus_per_task": True}, "cpus_per_task must be a whole number"),
        ({"mem_gb": "8G"}, "mem_gb must be a positive number, got '8G'"),
        ({"setup": "module load cuda"}, "setup must be a list of shell lines"),
        ({"slurm_additional": ["--qos=x"]}, "slurm_additional maps sbatch options to values"),
        ({"partition": 3}, "partition must be a name"),
    ],
)
def test_a_bad_cluster_section_is_refused_in_one_line(tmp_path, cluster, message):
    with pytest.raises(StudyError, match=message):
        load_study(write(tmp_path, {"root": "r", "runs": [{"name": "a"}], "cluster": cluster}))


# --- job files and job states --------------------------------------------------------------------------------------


def test_resubmissions_count_the_jobs_in_a_row_that_ended_without_progress(tmp_path):
    d = tmp_path / "run"
    assert sc.saved_frames(d) == 0
    (d / "checkpoints" / "state").mkdir(parents=True)
    (d / "checkpoints" / "state" / "COMPLETE").write_text("256")
    (d / "checkpoints" / "state.old").mkdir()
    (d / "checkpoints" / "state.old" / "COMPLETE").write_text("128")
    assert sc.saved_frames(d) == 256
    jobs = [
        {"job_id": "1", "ended": "TIMEOUT", "progress": True},
        {"job_id": "2", "ended": "FAILED", "progress": False},
        {"job_id": "3", "ended": "DIED", "progress": False},
    ]
    assert sc.failures_in_a_row({"jobs": jobs}) == 2
    assert sc.failures_in_a_row({"jobs": jobs + [{"job_id": "4"}]}) == 0  # the last one still runs
    assert sc.failures_in_a_row({"jobs": jobs, "count_from": 2}) == 1  # a later call retried it after job 2
    note = sc.describe_jobs({"executor": "slurm", "jobs": jobs}, "DIED", 3)
    assert note == "[slurm job 3 DIED, 3 jobs; 2 ended without progress (3 resubmissions allowed)]"
    gone = sc.describe_jobs({"executor": "slurm", "jobs": jobs, "given_up": "4 jobs in a row"}, "DIED", 3)
    assert gone.endswith("; given up: 4 jobs in a row]")
    assert sc.ended("CANCELLED by 0") and sc.ended("GONE") and not sc.ended("PENDING") and not sc.ended("UNKNOWN")


def test_a_local_job_runs_while_its_controller_lives_and_its_result_says_how_it_ended(tmp_path):
    folder = tmp_path / "submitit"
    folder.mkdir()
    # a stand-in for submitit's controller: its command line names the controller module and the job's folder
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)", "submitit.local._local", str(folder)])
    try:
        for _ in range(200):
            if str(folder) in Path(f"/proc/{proc.pid}/cmdline").read_bytes().decode():
                break
            time.sleep(0.05)
        assert sc.job_state("submitit-local", str(folder), str(proc.pid)) == "RUNNING"
        assert sc.job_state("submitit-local", str(tmp_path / "other"), str(proc.pid)) == "DIED"  # a recycled pid
    finally:
        proc.kill()
        proc.wait()
    assert sc.job_state("submitit-local", str(folder), str(proc.pid)) == "DIED"  # killed, no result written
    result = folder / f"{proc.pid}_0_result.pkl"
    result.write_bytes(pickle.dumps(("error", "Traceback ...")))
    assert sc.job_state("submitit-local", str(folder), str(proc.pid)) == "FAILED"
    result.write_bytes(pickle.dumps(("success", 0)))
    assert sc.job_state("submitit-local", str(folder), str(proc.pid)) == "COMPLETED"


def _fake_slurm(bin_dir: Path, squeue: str, sacct_rc: int = 1) -> Path:
    """``srun``/``sbatch``/``sacct``/``squeue``/``scancel`` stand-ins: sbatch numbers the jobs and keeps each script,
    squeue answers ``squeue`` (a shell snippet; ``$ids`` holds the ids asked), sacct fails as without accounting."""
    bin_dir.mkdir()
    scripts = {
        "srun": "exit 0",
        "sbatch": 'n=$(( $(cat "$0.count" 2>/dev/null || echo 0) + 1 )); echo $n > "$0.count"; '
        'cp "$1" "$0.script.$n"; echo "Submitted batch job $n"',
        "sacct": f"echo 'Slurm accounting storage is disabled' >&2; exit {sacct_rc}",
        "squeue": 'ids=""; while [ $# -gt 0 ]; do [ "$1" = -j ] && ids=$(echo "$2" | tr , " "); shift; done; ' + squeue,
        "scancel": 'echo "$@" >> "$0.calls"',
    }
    for name, body in scripts.items():
        (bin_dir / name).write_text(f"#!/bin/sh\n{body}\n")
        (bin_dir / name).chmod(0o755)
    return bin_dir


def test_slurm_states_come_from_squeue_where_sacct_knows_nothing(tmp_path, monkeypatch):
    fake = _fake_slurm(tmp_path / "bin", 'for i in $ids; do [ "$i" = 7 ] && echo "7 RUNNING"; done; exit 0')
    monkeypatch.setenv("PATH", f"{fake}:{os.environ['PATH']}")
    # 7 is listed; 8 is not any more (it ended long ago)
    assert sc.slurm_states([("f", "7"), ("f", "8")]) == {"7": "RUNNING", "8": "GONE"}
    (fake / "squeue").write_text("#!/bin/sh\necho 'slurm_load_jobs error: Invalid job id specified' >&2; exit 1\n")
    sc._SLURM_SEEN.clear()
    assert sc.slurm_states([("f", "9")]) == {"9": "GONE"}
    # Slurm does not answer (slurmctld down): the job counts as alive, so it is not submitted a second time
    (fake / "squeue").write_text("#!/bin/sh\necho 'Unable to contact slurm controller' >&2; exit 1\n")
    sc._SLURM_SEEN.clear()
    assert sc.slurm_states([("f", "9")]) == {"9": "UNKNOWN"} and not sc.ended("UNKNOWN")


def test_a_slurm_study_submits_its_settings_and_gives_up_a_run_whose_jobs_die_without_progress(
    tmp_path, monkeypatch, capsys
):
    """Through a stand-in sbatch: the sbatch script carries the study's resources, the job runs the command a local
    study would (with device=cuda for a GPU study), a job that ends without the run saving anything is resubmitted
    up to max_resubmits times and then given up, --status says so, and a later call tries again."""
    fake = _fake_slurm(tmp_path / "bin", 'for i in $ids; do echo "$i FAILED"; done')
    monkeypatch.setenv("PATH", f"{fake}:{os.environ['PATH']}")
    root = tmp_path / "runs"
    f = write(
        tmp_path,
        {
            "root": str(root),
            "runs": [{"name": "a", "args": ["total_frames=1000"]}],
            "cluster": {"partition": "gpu", "time_min": 90, "mem_gb": 8, "gpus": 1, "setup": ["module load cuda"]},
        },
    )
    rc = main([str(f), "--executor", "slurm", "--max-resubmits", "1", "--cpus-per-task", "3", "--partition", "a100"])
    out = capsys.readouterr().out
    assert rc == 1
    assert "a: starting (slurm job 1)" in out and "a: slurm job 1 FAILED, new" in out
    assert "a: its job ended before the run finished: resubmitting" in out and "a: starting (slurm job 2)" in out
    assert "a: given up: 2 jobs in a row ended without the run saving progress (the last: 2 FAILED)" in out
    script = (fake / "sbatch.script.1").read_text()
    for flag in (
        "--partition=a100",  # the command line's override
        "--time=90",
        "--mem=8GB",
        "--gpus-per-node=1",
        "--cpus-per-task=3",
        "--job-name=drs-a",
        "module load cuda",
    ):
        assert flag in script, flag
    job = pickle.loads((root / "logs" / "submitit" / "a" / "1_submitted.pkl").read_bytes()).function
    assert isinstance(job, sc.RunCommand) and job.cwd == os.getcwd() and job.log == str(root / "logs" / "a.log")
    assert job.command[0] == str(BIN / "drs-learn") and job.command[-3:] == [
        f"hydra.run.dir={root / 'a'}",
        "torch_threads=3",  # one per CPU of the job
        "device=cuda",
    ]
    assert job.env == {"OMP_NUM_THREADS": "3", "MKL_NUM_THREADS": "3"}
    rec = sc.read_jobs(root, "a")
    assert [j["job_id"] for j in rec["jobs"]] == ["1", "2"] and rec["given_up"].startswith("2 jobs in a row")
    assert main([str(f), "--status", "--max-resubmits", "1"]) == 0
    line = capsys.readouterr().out.splitlines()[0]
    assert line.startswith("       new  ") and "[slurm job 2 FAILED, 2 jobs; given up: 2 jobs in a row" in line
    # a later call tries the run again, counting afresh
    assert main([str(f), "--executor", "slurm", "--max-resubmits", "0"]) == 1
    out = capsys.readouterr().out
    assert "a: given up earlier (2 jobs in a row" in out and "trying again" in out
    assert "a: starting (slurm job 3)" in out and "slurm job 4" not in out


def test_slurm_where_there_is_none_is_refused_in_one_line_and_cancel_says_when_nothing_runs(
    tmp_path, monkeypatch, capsys
):
    f = write(tmp_path, {"root": str(tmp_path / "runs"), "runs": [{"name": "a", "args": ["total_frames=1000"]}]})
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    assert main([str(f), "--executor", "slurm"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("drs-study: error: --executor slurm: no sbatch or srun here") and err.count("\n") == 1
    assert main([str(f), "--executor", "slurm", "--check"]) == 0  # the configs are checked anywhere
    assert not (tmp_path / "runs").exists()
    assert main([str(f), "--cancel"]) == 0
    assert f"drs-study: no job of {f} is queued or running" in capsys.readouterr().out


def test_a_job_slurm_does_not_take_is_refused_in_one_line_and_nothing_is_recorded(tmp_path, monkeypatch, capsys):
    """sbatch failing (here: slurmctld down) had ended drs-study as an "internal error, a bug rather than your
    input" with submitit's traceback; it is a one-line refusal naming sbatch's reason and what to check."""
    fake = _fake_slurm(tmp_path / "bin", "exit 0")
    (fake / "sbatch").write_text(
        "#!/bin/sh\necho 'sbatch: error: Batch job submission failed: Unable to contact slurm controller "
        "(connect failure)' >&2\nexit 1\n"
    )
    monkeypatch.setenv("PATH", f"{fake}:{os.environ['PATH']}")
    root = tmp_path / "runs"
    f = write(tmp_path, {"root": str(root), "runs": [{"name": "a", "args": ["total_frames=1000"]}]})
    with pytest.raises(SystemExit) as exit_:
        main([str(f), "--executor", "slurm"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err  # (sbatch's own line may come first: it writes to the terminal too)
    ours = err.splitlines()[-1]
    assert ours.startswith("drs-study: error: slurm did not take run a's job (sbatch: error: Batch job submission")
    assert "Unable to contact slurm controller" in ours and "sinfo" in ours and "Traceback" not in err
    assert sc.read_jobs(root, "a") is None  # no job recorded for the run: the next call submits it


def test_a_restarted_driver_follows_a_live_job_and_never_submits_a_second_one(tmp_path, monkeypatch, capsys):
    """The job file names a job Slurm still runs: --status shows it, another call follows it (no sbatch), a second
    driver on the same root is refused, and --cancel cancels it."""
    fake = _fake_slurm(tmp_path / "bin", 'for i in $ids; do echo "$i RUNNING"; done')
    monkeypatch.setenv("PATH", f"{fake}:{os.environ['PATH']}")
    root = tmp_path / "runs"
    f = write(tmp_path, {"root": str(root), "runs": [{"name": "a", "args": ["total_frames=1000"]}]})
    (root / "logs").mkdir(parents=True)
    sc.write_jobs(root, "a", {"executor": "slurm", "folder": str(root / "logs/submitit/a"), "jobs": [{"job_id": "41"}]})
    assert main([str(f), "--status"]) == 0
    assert capsys.readouterr().out.splitlines()[0] == f"   running  {root / 'a'}  [slurm job 41 RUNNING]"
    # a driver following the job: it stops (here at once: SIGTERM) and leaves the job be
    holder = _driver_lock_holder(root)
    try:
        assert main([str(f), "--executor", "slurm"]) == 2
        assert f"another drs-study call (pid {holder.pid}) follows the jobs of {root}" in capsys.readouterr().err
        assert main([str(f), "--cancel"]) == 2
    finally:
        holder.kill()
        holder.wait()
    monkeypatch.setattr(signal, "signal", _stop_at_once(signal.signal))
    assert main([str(f), "--executor", "slurm"]) == 130
    out = capsys.readouterr().out
    assert "a: following slurm job 41" in out and "the jobs keep going: a (job 41)" in out
    assert not (fake / "sbatch.count").exists()  # nothing submitted
    # a local study call leaves the run to its job
    monkeypatch.undo()
    monkeypatch.setenv("PATH", f"{fake}:{os.environ['PATH']}")
    assert main([str(f)]) == 0
    assert "a: being trained by another call (slurm job 41), skipped" in capsys.readouterr().out
    assert main([str(f), "--cancel"]) == 0
    assert "a: slurm job 41 cancelled" in capsys.readouterr().out
    assert "41" in (fake / "scancel.calls").read_text()


def _driver_lock_holder(root: Path) -> subprocess.Popen:
    """Another process holding the run root's driver lock, as a running drs-study --executor call does."""
    script = (
        "import fcntl, sys, time; f = open(sys.argv[1], 'a+'); fcntl.flock(f, fcntl.LOCK_EX); "
        "f.truncate(0); f.write(str(__import__('os').getpid())); f.flush(); print('locked', flush=True); time.sleep(60)"
    )
    p = subprocess.Popen(
        [sys.executable, "-c", script, str(root / "logs" / "driver.lock")], stdout=subprocess.PIPE, text=True
    )
    assert p.stdout.readline().strip() == "locked"
    return p


def _stop_at_once(real_signal):
    """``signal.signal`` that, once the study installs its SIGINT handler, calls it (Ctrl-C at the first moment)."""

    def install(signum, handler):
        previous = real_signal(signum, handler)
        if signum == signal.SIGINT and callable(handler) and handler not in (signal.default_int_handler,):
            handler(signal.SIGINT, None)
        return previous

    return install


def test_a_job_at_its_time_limit_lets_its_run_save_before_it_ends(tmp_path):
    """submitit signals a job before its time limit: RunCommand passes SIGTERM to the run (which saves and stops, as
    drs-learn does) and waits for it, so the job's end leaves a resumable state."""
    import submitit

    run = tmp_path / "run.py"
    run.write_text(
        "import signal, sys, time\n"
        "def save(*_):\n    open(sys.argv[1], 'w').write('saved'); sys.exit(143)\n"
        "signal.signal(signal.SIGTERM, save)\nprint('running', flush=True)\ntime.sleep(120)\n"
    )
    ex = submitit.LocalExecutor(folder=tmp_path / "submitit")
    ex.update_parameters(timeout_min=0.25, signal_delay_s=11)  # the time-limit signal 4 s in
    log, mark = tmp_path / "run.log", tmp_path / "saved"
    job = ex.submit(sc.RunCommand([sys.executable, str(run), str(mark)], str(log), str(tmp_path)))
    t0 = time.time()
    while not job.done() and time.time() - t0 < 60:
        time.sleep(0.2)
    assert mark.read_text() == "saved" and "running" in log.read_text()
    assert sc.job_state("submitit-local", str(tmp_path / "submitit"), job.job_id, job) == "FAILED"
    assert "checkpoint function returned None" in str(job.exception())  # not requeued by submitit: by the study


# --- end to end -----------------------------------------------------------------------------------------------------


def _study(tmp_path, cluster: dict | None = None) -> Path:
    """A phase-1 run and a reuse run that needs it, a few hundred env steps each, saved every 128."""
    small = [
        *tiny(frames=640, learning_starts=512, eval_episodes=0, checkpoint_every=128),
        "algo.precision=fp32",
        "+env.variant_overrides.goal_thresh=0.08",
    ]
    spec = {
        "root": str(tmp_path / "runs"),
        "common": small,
        "runs": [
            {"name": "learn", "args": ["seed=1"]},
            {
                "name": "reuse",
                "app": "reuse",
                "needs": ["learn"],
                "args": ["reward=drs", "reward.checkpoint=<reward:learn>", "env.split=train"],
            },
        ],
    }
    if cluster:
        spec["cluster"] = cluster
    return write(tmp_path, spec)


def _wait(condition, seconds: float, what: str, logs: Path):
    t0 = time.time()
    while not condition():
        if time.time() - t0 > seconds:
            raise AssertionError(f"{what} after {seconds} s; logs: " + _tails(logs))
        time.sleep(0.1)


def _tails(logs: Path) -> str:
    return "".join(
        f"\n--- {p}\n{p.read_text()[-2000:]}" for p in sorted(logs.rglob("*.log")) + sorted(logs.rglob("*.out"))
    )


def _tree(pid: int) -> list[int]:
    """``pid`` and every process descending from it."""
    children: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                children.setdefault(int((d / "stat").read_text().rsplit(")", 1)[1].split()[1]), []).append(int(d.name))
            except (OSError, ValueError, IndexError):
                continue
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo += children.get(p, [])
    return out


@pytest.mark.sim
@pytest.mark.slow
def test_a_study_on_submitit_local_survives_a_killed_driver_and_a_dead_job(tmp_path):
    """Phase 1 and the reuse run that needs it, as submitit jobs on this machine. The driver is killed once the
    phase-1 run has saved (its job goes on), a new driver follows that job rather than submitting another, the job
    is then killed outright, and the driver resubmits the run with resume=; then the reuse run; nothing twice."""
    f = _study(tmp_path)
    root = tmp_path / "runs"
    drs = [str(BIN / "drs-study"), str(f)]
    first = open(tmp_path / "driver1.out", "w")
    d1 = subprocess.Popen(
        [*drs, "--executor", "submitit-local"], stdout=first, stderr=subprocess.STDOUT, start_new_session=True
    )
    _wait(lambda: sc.saved_frames(root / "learn") > 0, 300, "phase 1 saved no state", tmp_path)
    d1.kill()  # the driver dies (its job does not)
    d1.wait()
    job = sc.read_jobs(root, "learn")["jobs"][-1]["job_id"]
    trainer = int((root / "learn" / ".drs-lock").read_text().split()[0])
    os.kill(trainer, signal.SIGSTOP)  # the run stays where it is until its job is killed below
    status = subprocess.run([*drs, "--status"], capture_output=True, text=True, timeout=120)
    assert f"   running  {root / 'learn'}  [submitit-local job {job} RUNNING]" in status.stdout, status.stdout
    (tmp_path / "status_live_job.txt").write_text(status.stdout)
    second = tmp_path / "driver2.out"
    d2 = subprocess.Popen([*drs, "--executor", "submitit-local"], stdout=open(second, "w"), stderr=subprocess.STDOUT)
    try:
        _wait(lambda: f"learn: following submitit-local job {job}" in second.read_text(), 120, "not followed", tmp_path)
        for pid in _tree(int(job)):  # the job dies outright: its controller, submitit's process, the run
            os.kill(pid, signal.SIGKILL)
        assert d2.wait(timeout=400) == 0, _tails(tmp_path)
    finally:
        if d2.poll() is None:
            d2.kill()
    out = second.read_text()
    assert f"learn: submitit-local job {job} DIED, resumable" in out, out
    assert "learn: resuming (submitit-local job" in out and "reuse: starting (submitit-local job" in out
    assert "all 2 runs finished" in out
    learn, reuse = sc.read_jobs(root, "learn"), sc.read_jobs(root, "reuse")
    assert [j["ended"] for j in learn["jobs"]] == ["DIED", "COMPLETED"] and learn["jobs"][1]["resume"]
    assert [j["ended"] for j in reuse["jobs"]] == ["COMPLETED"]
    commands = [ln for ln in (root / "logs" / "learn.log").read_text().splitlines() if ln.startswith("# 2")]
    assert len(commands) == 2 and f"resume={root / 'learn'}" in commands[1]
    for name in ("learn", "reuse"):
        assert run_state(root / name) == "finished"
    summary = json.loads((root / "learn" / "summary.json").read_text())
    assert summary["frames"] == 640 and summary["resumed_from"] > 0
    p = subprocess.run([*drs, "--executor", "submitit-local"], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0 and p.stdout.count("finished, skipped") == 2
    assert len(sc.read_jobs(root, "learn")["jobs"]) == 2  # nothing submitted again


@pytest.mark.sim
@pytest.mark.slow
@pytest.mark.skipif(shutil.which("sbatch") is None, reason="no Slurm here (bin/slurm-local.sh starts one)")
def test_a_study_on_slurm_resubmits_a_cancelled_job_with_resume(tmp_path):
    """The same study through a real Slurm (bin/slurm-local.sh): scancel of the phase-1 job (the run saves on
    Slurm's SIGTERM) is a job that ended before its run finished, resubmitted with resume=."""
    f = _study(tmp_path, {"time_min": 10, "cpus_per_task": 1, "mem_gb": 1})
    root = tmp_path / "runs"
    drs = [str(BIN / "drs-study"), str(f)]
    out = tmp_path / "driver.out"
    d = subprocess.Popen([*drs, "--executor", "slurm"], stdout=open(out, "w"), stderr=subprocess.STDOUT)
    try:
        _wait(lambda: sc.saved_frames(root / "learn") > 0, 300, "phase 1 saved no state", tmp_path)
        job = sc.read_jobs(root, "learn")["jobs"][-1]["job_id"]
        status = subprocess.run([*drs, "--status"], capture_output=True, text=True, timeout=120)
        assert f"   running  {root / 'learn'}  [slurm job {job} RUNNING]" in status.stdout, status.stdout
        subprocess.run(["scancel", job], check=True)
        assert d.wait(timeout=400) == 0, _tails(tmp_path)
    finally:
        if d.poll() is None:
            d.kill()
    text = out.read_text()
    assert f"learn: slurm job {job} CANCELLED, resumable" in text, text
    assert "learn: resuming (slurm job" in text and "all 2 runs finished" in text
    learn = sc.read_jobs(root, "learn")
    assert [j["ended"] for j in learn["jobs"]] == ["CANCELLED", "COMPLETED"] and learn["jobs"][1]["resume"]
    assert len(sc.read_jobs(root, "reuse")["jobs"]) == 1
    for name in ("learn", "reuse"):
        assert run_state(root / name) == "finished"
