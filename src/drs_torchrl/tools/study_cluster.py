"""``drs-study --executor submitit-local|slurm``: a study's runs as submitit jobs, followed across driver restarts.

The study's scheduling loop (``study.main``) is the same for every executor; this module is what differs when a
run is a submitit job rather than a child process of the driver:

* :class:`Cluster`, the study file's ``cluster:`` section (partition, time limit, CPUs, memory, GPUs, how many
  jobs at once, how many resubmissions without progress), with the command line's overrides;
* :class:`RunCommand`, what a job runs: the run's command (exactly the one a local study would start), its output
  appended to ``<root>/logs/<run>.log``; on submitit's time-limit or preemption signal the run is asked to save
  (SIGTERM) and the job waits for it, so the next job resumes it (``resume=``);
* the job files ``<root>/logs/<run>.job.json``, one per run: every job submitted for it (executor, submitit
  folder, job id, time, the frames its saved state held then, how it ended), so that a driver started again
  re-attaches to a job still queued or running instead of submitting a second one, and resubmits a run whose job
  died; :func:`job_state` asks submitit (and ``squeue`` where ``sacct`` knows nothing) what became of a job;
* :class:`SubmititRuns`, the driver's side: submit, follow, cancel.
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import pickle
import shlex
import signal
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

from drs_torchrl.runtime.errors import UserError

EXECUTORS = ("local", "submitit-local", "slurm")
_SUBMITIT_CLUSTER = {"submitit-local": "local", "slurm": "slurm"}

# how a job can end (Slurm's states, submitit-local's): anything else (PENDING, RUNNING, REQUEUED, COMPLETING,
# UNKNOWN: sacct and squeue both failed, ...) counts as a job still alive, so that no run is ever submitted twice
ENDED = {
    "COMPLETED",
    "FAILED",
    "CANCELLED",
    "TIMEOUT",
    "OUT_OF_MEMORY",
    "NODE_FAIL",
    "BOOT_FAIL",
    "DEADLINE",
    "GONE",  # Slurm no longer lists it (sacct has no record, squeue forgot it): it ended long ago
    "DIED",  # submitit-local: its controller is gone without writing a result (killed)
}


def ended(state: str) -> bool:
    """Whether a job in ``state`` (:func:`job_state`) has ended; ``CANCELLED by 0`` is ``CANCELLED``."""
    return state.split()[0] in ENDED if state else False


class SubmitError(UserError, RuntimeError):
    """A job the cluster did not take (sbatch refused it): an environment or settings problem, not a bug."""


# --- the study file's cluster: section ------------------------------------------------------------------------------

_KEYS = {
    "partition": "the Slurm partition (sbatch --partition)",
    "time_min": "each job's time limit in minutes; a run that reaches it saves and is resubmitted with resume=",
    "cpus_per_task": "CPUs per job (sbatch --cpus-per-task); also the runs' torch threads unless --threads says",
    "mem_gb": "memory per job in GB (sbatch --mem)",
    "gpus": "GPUs per job (sbatch --gpus-per-node); > 0 also runs each run with device=cuda",
    "max_jobs": "jobs queued or running at once (default: all that are ready; submitit-local: --jobs)",
    "max_resubmits": "jobs in a row that may end without the run saving progress before it is given up (default 3)",
    "signal_delay_s": "Slurm: seconds before the time limit at which a run is told to save (default 90)",
    "setup": "shell lines run in each Slurm job before the run (module load ..., source .venv/bin/activate)",
    "slurm_additional": "more sbatch options as a mapping (account: x, qos: y, constraint: z)",
}


@dataclass
class Cluster:
    """How a study's runs are submitted: the study file's ``cluster:`` section, overridden by the command line."""

    partition: str | None = None
    time_min: int = 1440
    cpus_per_task: int | None = None
    mem_gb: float | None = None
    gpus: int = 0
    max_jobs: int | None = None
    max_resubmits: int = 3
    signal_delay_s: int | None = None
    setup: list[str] = field(default_factory=list)
    slurm_additional: dict[str, str] = field(default_factory=dict)

    def executor_parameters(self, executor: str) -> dict:
        """``AutoExecutor.update_parameters`` keywords: the generic ones for both, Slurm's own for Slurm only."""
        params: dict = {"timeout_min": self.time_min}
        if self.gpus:
            params["gpus_per_node"] = self.gpus
        if executor == "slurm":
            if self.cpus_per_task is not None:
                params["cpus_per_task"] = self.cpus_per_task
            if self.mem_gb is not None:
                params["mem_gb"] = self.mem_gb
            if self.partition:
                params["slurm_partition"] = self.partition
            if self.signal_delay_s is not None:
                params["slurm_signal_delay_s"] = self.signal_delay_s
            if self.setup:
                params["slurm_setup"] = list(self.setup)
            if self.slurm_additional:
                params["slurm_additional_parameters"] = dict(self.slurm_additional)
        return params


def parse_cluster(spec) -> Cluster:
    """A study file's ``cluster:`` mapping as a :class:`Cluster`; ``ValueError`` names the first bad key."""
    if spec is None:
        return Cluster()
    if not isinstance(spec, dict):
        raise ValueError(f"a mapping of {', '.join(_KEYS)}, got {type(spec).__name__} {spec!r}")
    unknown = sorted(set(spec) - set(_KEYS))
    if unknown:
        raise ValueError(f"unknown keys {unknown} (allowed: {', '.join(_KEYS)})")
    c = Cluster()
    for key, value in spec.items():
        if value is None:
            continue
        if key == "partition":
            if not isinstance(value, str) or not value:
                raise ValueError(f"partition must be a name, got {value!r}")
        elif key == "mem_gb":
            if isinstance(value, bool) or not isinstance(value, (int, float)) or value <= 0:
                raise ValueError(f"mem_gb must be a positive number, got {value!r}")
        elif key == "setup":
            if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
                raise ValueError(f"setup must be a list of shell lines, got {value!r}")
        elif key == "slurm_additional":
            if not isinstance(value, dict) or not all(isinstance(v, (str, int, float)) for v in value.values()):
                raise ValueError(f"slurm_additional maps sbatch options to values, got {value!r}")
            value = {str(k): str(v) for k, v in value.items()}
        else:
            low = 0 if key in ("gpus", "max_resubmits", "signal_delay_s") else 1
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"{key} must be a whole number >= {low}, got {value!r}")
        setattr(c, key, value)
    return c


# --- what a job runs ----------------------------------------------------------------------------------------------


@dataclass
class RunCommand:
    """A study run as a submitit job: ``command`` in ``cwd`` with ``env`` on top of the job's environment, its
    output appended to ``log``. Its exit status is the job's: a run that stops short (interrupted, crashed) fails
    the job, and the study resubmits it."""

    command: list[str]
    log: str
    cwd: str
    env: dict[str, str] = field(default_factory=dict)

    def __call__(self) -> int:
        with open(self.log, "a") as out:
            proc = subprocess.Popen(
                self.command, stdout=out, stderr=subprocess.STDOUT, cwd=self.cwd, env={**os.environ, **self.env}
            )
        self._proc = proc
        try:
            while proc.poll() is None:
                time.sleep(0.5)
        except BaseException:  # submitit's time-limit handler (below), Ctrl-C, SystemExit: let the run save first
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
            proc.wait()
            raise
        if proc.returncode != 0:
            raise RuntimeError(f"{shlex.join(self.command[:1])} exited {proc.returncode} (see {self.log})")
        return 0

    def checkpoint(self, *args, **kwargs) -> None:
        """Called by submitit on the signal it gets before the time limit (or a preemption): the run saves at its
        next batch boundary (SIGTERM) while :meth:`__call__` waits for it. Returns None, so submitit does not
        requeue the job itself: the study resubmits the run with ``resume=``."""
        proc = getattr(self, "_proc", None)
        if proc is not None and proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        return None

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "_proc"}


# --- job files ----------------------------------------------------------------------------------------------------


def job_file(root: Path, name: str) -> Path:
    """Where a study records the jobs it submitted for run ``name`` (``ROOT/logs/NAME.job.json``)."""
    return root / "logs" / f"{name}.job.json"


def read_jobs(root: Path, name: str) -> dict | None:
    """Run ``name``'s job file (``{"executor", "folder", "jobs": [...], "given_up"}``), or None."""
    try:
        rec = json.loads(job_file(root, name).read_text())
    except (OSError, ValueError):
        return None
    return rec if isinstance(rec, dict) and rec.get("jobs") else None


def write_jobs(root: Path, name: str, rec: dict) -> None:
    f = job_file(root, name)
    tmp = f.with_suffix(".tmp")
    tmp.write_text(json.dumps(rec, indent=1) + "\n")
    tmp.replace(f)  # a driver killed while writing leaves the previous record


def saved_frames(run_dir: Path) -> int:
    """The env steps a run's saved training state holds (its ``COMPLETE`` marker), 0 where it has none."""
    best = 0
    for name in ("state", "state.old"):
        with contextlib.suppress(OSError, ValueError):
            best = max(best, int((run_dir / "checkpoints" / name / "COMPLETE").read_text().strip() or 0))
    return best


def failures_in_a_row(rec: dict) -> int:
    """How many of a run's last jobs ended without its saved state advancing (since a study call last retried a run
    it had given up: ``count_from``)."""
    n = 0
    for j in reversed(rec.get("jobs", [])[rec.get("count_from", 0) :]):
        if "ended" not in j or j.get("progress", True):
            break
        n += 1
    return n


# --- job states ---------------------------------------------------------------------------------------------------


def _local_state(folder: str, job_id: str, job=None) -> str:
    """A submitit-local job: RUNNING while its controller lives, else COMPLETED/FAILED by the result it wrote, or
    DIED (killed before it wrote one)."""
    import submitit

    if job is not None:
        job.get_info()  # polls (and reaps) the controller this driver started
    try:
        cmdline = Path(f"/proc/{int(job_id)}/cmdline").read_bytes().decode(errors="replace").replace("\0", " ")
    except (OSError, ValueError):
        cmdline = ""
    # a pid can be recycled: the controller's command line names submitit's local controller and the job's folder
    if "submitit.local._local" in cmdline and str(folder) in cmdline:
        return "RUNNING"
    result = submitit.LocalJob(folder, job_id).paths.result_pickle
    if not result.is_file():
        return "DIED"
    try:
        outcome = pickle.loads(result.read_bytes())[0]
    except Exception:
        return "FAILED"
    return "COMPLETED" if outcome == "success" else "FAILED"


def _squeue_states(ids: list[str]) -> dict[str, str]:
    """Slurm's own word on jobs sacct does not know (a cluster without accounting): ``squeue -t all``; a job it no
    longer lists is GONE; no answer at all (slurmctld unreachable) leaves them UNKNOWN, i.e. alive."""
    try:
        p = subprocess.run(
            ["squeue", "-h", "-t", "all", "-j", ",".join(ids), "-o", "%i %T"],
            capture_output=True,
            text=True,
            timeout=60,
        )
    except (OSError, subprocess.TimeoutExpired):
        return dict.fromkeys(ids, "UNKNOWN")
    if p.returncode != 0:
        return dict.fromkeys(ids, "GONE" if "Invalid job id" in p.stderr else "UNKNOWN")
    listed = dict(line.split(None, 1) for line in p.stdout.splitlines() if len(line.split(None, 1)) == 2)
    return {i: listed.get(i, "GONE").strip() for i in ids}


# Slurm states asked less than this many seconds ago are not asked again (a study's --status, its report and the
# driver's loop ask about every run; one sacct call answers for all the jobs asked at once)
SLURM_TTL_S = 5.0
_SLURM_SEEN: dict[str, tuple[float, str]] = {}


@functools.lru_cache(maxsize=1)
def _has_sacct() -> bool:
    """Whether ``sacct`` answers here (a cluster without an accounting database refuses every call, loudly)."""
    try:
        return (
            subprocess.run(["sacct", "-n", "-X", "-j", "1", "-o", "JobID"], capture_output=True, timeout=60).returncode
            == 0
        )
    except (OSError, subprocess.TimeoutExpired):
        return False


def slurm_states(folder_ids: list[tuple[str, str]]) -> dict[str, str]:
    """States of Slurm jobs ``(folder, job_id)``: submitit's (sacct, one call for all), squeue where it says UNKNOWN."""
    import logging

    import submitit

    now = time.monotonic()
    fresh = {}
    for _, i in folder_ids:
        seen = _SLURM_SEEN.get(i)
        if seen is not None and now - seen[0] < SLURM_TTL_S:
            fresh[i] = seen[1]
    ask = [(f, i) for f, i in folder_ids if i not in fresh]
    if not ask:
        return fresh
    if _has_sacct():
        logging.getLogger("submitit").setLevel(logging.ERROR)  # sacct's passing failures are answered by squeue
        jobs = [submitit.SlurmJob(folder, job_id) for folder, job_id in ask]  # all registered, then one sacct call
        states = {j.job_id: (j.state or "UNKNOWN").upper() for j in jobs}
    else:
        states = {job_id: "UNKNOWN" for _, job_id in ask}
    unknown = [i for i, s in states.items() if s == "UNKNOWN"]
    if unknown:
        states.update(_squeue_states(unknown))
    _SLURM_SEEN.update({i: (now, s) for i, s in states.items()})
    return {**fresh, **states}


def job_state(executor: str, folder: str, job_id: str, job=None) -> str:
    """One job's state; ``job``: the submitit job object when this driver submitted it."""
    if executor == "submitit-local":
        return _local_state(folder, job_id, job)
    return slurm_states([(folder, job_id)])[job_id]


def last_job_states(root: Path, names: list[str]) -> dict[str, tuple[dict, str]]:
    """For each run with a job file: (its job file, the state of its last job); one Slurm query for all."""
    recs = {n: rec for n in names if (rec := read_jobs(root, n)) is not None}
    slurm = [(rec["folder"], rec["jobs"][-1]["job_id"]) for rec in recs.values() if rec["executor"] == "slurm"]
    known = slurm_states(slurm) if slurm else {}
    out = {}
    for n, rec in recs.items():
        last = rec["jobs"][-1]
        if "ended" in last:
            state = last["ended"]
        elif rec["executor"] == "slurm":
            state = known.get(last["job_id"], "UNKNOWN")
        else:
            state = _local_state(rec["folder"], last["job_id"])
        out[n] = (rec, state)
    return out


def live_job(root: Path, name: str) -> str | None:
    """``"slurm job 1234"`` while run ``name``'s last job is queued or running, else None."""
    rec = read_jobs(root, name)
    if rec is None or "ended" in rec["jobs"][-1]:
        return None
    last = rec["jobs"][-1]
    state = job_state(rec["executor"], rec["folder"], last["job_id"])
    return None if ended(state) else f"{rec['executor']} job {last['job_id']}"


def describe_jobs(rec: dict, state: str, max_resubmits: int) -> str:
    """``--status``'s note on a run's jobs: the last one's id and state, resubmissions used, given up."""
    last = rec["jobs"][-1]
    note = f"{rec['executor']} job {last['job_id']} {state}"
    if len(rec["jobs"]) > 1:
        note += f", {len(rec['jobs'])} jobs"
    fails = failures_in_a_row(rec)
    if rec.get("given_up"):
        note += f"; given up: {rec['given_up']}"
    elif fails:
        note += f"; {fails} ended without progress ({max_resubmits} resubmissions allowed)"
    return f"[{note}]"


# --- the driver's side --------------------------------------------------------------------------------------------


@dataclass
class Submitted:
    """A job this driver follows: its id and, when this driver submitted it, submitit's job object."""

    job_id: str
    job: object = None


class SubmititRuns:
    """Submits a study's runs through submitit (``AutoExecutor``, cluster ``slurm`` or ``local``) and follows them."""

    def __init__(self, executor: str, root: Path, cluster: Cluster):
        if executor not in _SUBMITIT_CLUSTER:
            raise ValueError(f"executor must be one of {', '.join(_SUBMITIT_CLUSTER)}, got {executor!r}")
        self.executor, self.root, self.cluster = executor, root, cluster

    def folder(self, name: str) -> Path:
        """submitit's folder for run ``name``'s jobs (pickles, the job's own logs, the sbatch script)."""
        return self.root / "logs" / "submitit" / name

    def submit(self, name: str, cmd: list[str], log: Path, env: dict[str, str]) -> Submitted:
        """Submit ``cmd`` (run ``name``'s command) as a job; record it in the run's job file."""
        import submitit

        ex = submitit.AutoExecutor(folder=self.folder(name), cluster=_SUBMITIT_CLUSTER[self.executor])
        ex.update_parameters(name=f"drs-{name}", **self.cluster.executor_parameters(self.executor))
        try:
            job = ex.submit(RunCommand(list(cmd), str(log), os.getcwd(), dict(env)))
        except submitit.core.utils.FailedJobError as exc:  # sbatch said no: Slurm down, a bad partition, ...
            said = next((ln.strip() for ln in str(exc).splitlines() if ln.strip()), "no message")
            raise SubmitError(
                f"{self.executor} did not take run {name}'s job ({said}); check that Slurm answers (sinfo) and the "
                "study's cluster settings (partition, time, memory), then start drs-study again: finished runs are "
                "skipped, nothing was submitted for this one"
            ) from None
        rec = read_jobs(self.root, name) or {"executor": self.executor, "folder": str(self.folder(name)), "jobs": []}
        rec.update(executor=self.executor, folder=str(self.folder(name)), given_up=None)
        rec["jobs"].append(
            {
                "job_id": str(job.job_id),
                "submitted": time.strftime("%Y-%m-%d %H:%M:%S"),
                "resume": any(c.startswith("resume=") for c in cmd),
                "saved_frames": saved_frames(self.root / name),
            }
        )
        write_jobs(self.root, name, rec)
        return Submitted(str(job.job_id), job)

    def attach(self, name: str) -> Submitted | None:
        """The job to follow for run ``name`` if its last job is still queued or running (a driver started again)."""
        rec = read_jobs(self.root, name)
        if rec is None or "ended" in rec["jobs"][-1]:
            return None
        job_id = rec["jobs"][-1]["job_id"]
        return None if ended(job_state(rec["executor"], rec["folder"], job_id)) else Submitted(job_id)

    def refresh(self, names: list[str]) -> None:
        """Ask Slurm once about the last jobs of runs ``names`` (:meth:`state` then answers from that)."""
        recs = [read_jobs(self.root, n) for n in names]
        slurm_states([(r["folder"], r["jobs"][-1]["job_id"]) for r in recs if r and r["executor"] == "slurm"])

    def state(self, name: str, sub: Submitted) -> str:
        rec = read_jobs(self.root, name) or {}
        return job_state(
            rec.get("executor", self.executor), rec.get("folder", str(self.folder(name))), sub.job_id, sub.job
        )

    def close(self, name: str, state: str) -> dict:
        """Record how run ``name``'s last job ended and whether its saved state advanced; its job file."""
        rec = read_jobs(self.root, name)
        last = rec["jobs"][-1]
        if "ended" not in last:
            now = saved_frames(self.root / name)
            last.update(ended=state, saved_frames_after=now, progress=now > last.get("saved_frames", 0))
            write_jobs(self.root, name, rec)
        return rec

    def give_up(self, name: str, why: str) -> None:
        rec = read_jobs(self.root, name)
        rec["given_up"] = why
        write_jobs(self.root, name, rec)

    def cancel(self, name: str) -> str | None:
        """Cancel run ``name``'s live job (Slurm: ``scancel``, which sends the run SIGTERM: it saves; local: SIGINT
        to the job's controller, which stops the run the same way); ``"slurm job 1234"``, or None if none lives."""
        import submitit

        rec = read_jobs(self.root, name)
        live = live_job(self.root, name)
        if rec is None or live is None:
            return None
        job_id = rec["jobs"][-1]["job_id"]
        if rec["executor"] == "slurm":
            submitit.SlurmJob(rec["folder"], job_id).cancel(check=False)
        else:
            with contextlib.suppress(OSError):
                os.kill(int(job_id), signal.SIGINT)
        return live
