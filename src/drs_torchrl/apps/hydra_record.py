"""Hydra's record of a run (its ``.hydra`` folder) never lands over another run's, and a refused run leaves none.

Hydra writes ``hydra.output_subdir`` into the run directory before the app starts. The configs name it through the
``drs_hydra_subdir`` resolver below: ``.hydra`` for a new run, ``.hydra-new-<stamp>`` beside a run that a new one may
replace (``overwrite=true``), ``.hydra-resume-<stamp>`` for a resume and ``.hydra-refused-<pid>`` in a directory
another process writes. :func:`replaced` makes a new run's record the directory's ``.hydra`` once it has started;
:func:`discard_refused_record` removes the record of a run that was refused. (Hydra has no hook for this: its
record is written before any app code runs.) Used by drs-learn / drs-reuse (:mod:`.cli`) and drs-maze.
"""

from __future__ import annotations

import os
import shutil
from datetime import datetime
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import OmegaConf

from drs_torchrl.runtime.rundir import OldRun, RunDirBusyError, lock_run_dir

# files by which a directory is recognised as holding a run (Hydra's own .hydra/ is not one: it
# writes that for the new run before the app starts)
RUN_MARKERS = ("config.yaml", "summary.json", "train.csv", "eval.csv", "checkpoints")
SIDE_RECORDS = (".hydra-resume-", ".hydra-new-", ".hydra-refused-")

STARTED = datetime.now().strftime("%Y%m%d-%H%M%S")  # one stamp per process: resolvers run more than once


def holds_run(run_dir: Path) -> bool:
    return any((run_dir / m).exists() for m in RUN_MARKERS)


def _job_dir() -> str | None:
    """The directory of the Hydra job being started (None outside one, e.g. ``--cfg``)."""
    try:
        out = HydraConfig.get().runtime.output_dir
    except Exception:  # noqa: BLE001 (no Hydra job: nothing to lock)
        return None
    return str(out) if out else None


_REFUSED: dict[str, str] = {}  # job directory -> the side record of a job refused there (another process writes it)


def _run_dir_resolver(resume, default):
    return str(resume) if resume else default


def _hydra_subdir_resolver(resume, run_dir=None):
    """Where Hydra writes its record: ``.hydra`` for a new run, but never over another run's record
    (a resume, or a new run pointed at a directory that holds a run, writes beside it).

    Hydra asks for this just before it writes the record, so the run directory's lock is taken here; a
    directory another process holds gets the record beside, and the app then refuses and removes it."""
    if not resume and run_dir is not None and not str(run_dir).strip():
        return None  # hydra.run.dir= (an unset shell variable): no record in the working directory; the app refuses
    job = _job_dir()
    if job is not None and job in _REFUSED:
        return _REFUSED[job]  # asked again by the app: the same answer, even if the other writer is gone by now
    if job is not None:
        try:
            lock_run_dir(job)
        except RunDirBusyError:
            _REFUSED[job] = f".hydra-refused-{os.getpid()}"
            return _REFUSED[job]
    if resume:
        return ".hydra-resume-" + STARTED
    if run_dir and holds_run(Path(str(run_dir))):
        return ".hydra-new-" + STARTED
    return ".hydra"


OmegaConf.register_new_resolver("drs_run_dir", _run_dir_resolver, replace=True)
OmegaConf.register_new_resolver("drs_hydra_subdir", _hydra_subdir_resolver, replace=True)


def empty_run_dir() -> bool:
    """``hydra.run.dir=`` was given empty (e.g. ``hydra.run.dir=$RUN`` with ``RUN`` unset): Hydra would make the working
    directory the run directory."""
    return not str(HydraConfig.get().run.dir).strip()


EMPTY_RUN_DIR = (
    "hydra.run.dir is empty (an unset shell variable?); name the run's directory, e.g. hydra.run.dir=runs/my_run"
)


def current_record(run_dir: str | os.PathLike) -> Path | None:
    """The folder Hydra wrote this job's record into (None when it writes none)."""
    sub = HydraConfig.get().output_subdir
    return Path(run_dir) / sub if sub else None


def replaced(run_dir: Path, old: OldRun) -> None:
    """The new run has started: the old run's files go, and this run's Hydra record becomes the directory's ``.hydra``."""
    if not old:
        return
    old.drop()
    for stale in run_dir.glob(".hydra-resume-*"):
        shutil.rmtree(stale, ignore_errors=True)
    new = sorted(run_dir.glob(".hydra-new-*"))
    if new:
        shutil.rmtree(run_dir / ".hydra", ignore_errors=True)
        new[-1].rename(run_dir / ".hydra")


def discard_refused_record(
    record: Path | None, *, resume: bool = False, locked: bool = True, keep_side_record: bool = False
) -> None:
    """A refused run leaves what was there as it was: its side record goes (a failed resume, a new run refused
    beside a run or beside another writer; unless ``keep_side_record``), and so does the ``.hydra`` of a refused new
    run in a directory that holds no run (``locked``: this process took the directory's lock; else one Hydra made
    is removed if empty)."""
    if record is None:
        return
    if record.name.startswith(SIDE_RECORDS):
        if keep_side_record:
            return
        shutil.rmtree(record, ignore_errors=True)
        if not locked:
            try:
                record.parent.rmdir()  # only if Hydra made it for a path that was not a run
            except OSError:
                pass
    elif record.name == ".hydra" and not resume and not holds_run(record.parent):
        shutil.rmtree(record, ignore_errors=True)
