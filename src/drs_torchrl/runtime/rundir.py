"""The files of a run: one writer per run directory, room on disk before a save, paths checked first.

* :func:`lock_run_dir` takes an exclusive ``flock`` on ``RUN_DIR/.drs-lock`` (holding the holder's pid) for
  the life of the process (or until :func:`unlock_run_dir`); a second process asking for it gets
  :class:`RunDirBusyError` naming that pid. The file goes when the lock is released; the kernel drops the
  lock of a process that dies, so a file left by a killed one never blocks. It is not a run file: it
  neither makes a directory look like a run nor is copied into a record.
* :func:`ensure_free` refuses a write whose bytes (estimated with :func:`nbytes` from the tensors to be
  written) do not fit on the filesystem, before a memory map would fault (SIGBUS) on a full disk;
  :func:`space_errors` turns ``ENOSPC`` from a write into the same :class:`DiskFullError`.
* :func:`check_writable` fails at once on an output path that cannot be written later (a file where a
  folder is needed, a folder where a file is, a read-only place), not after minutes of work.
* :func:`clear_for_new_run` refuses a directory that holds a run, or (``overwrite=true``) sets that run's files
  aside until the new run has started, so a replacement refused by a later check loses nothing.
* :func:`load_run_config` reads a run's ``config.yaml``, or says how it is damaged and where a copy is.
"""

from __future__ import annotations

import atexit
import contextlib
import errno
import fcntl
import os
import shutil
from pathlib import Path

from drs_torchrl.runtime.console import UserError

LOCK_NAME = ".drs-lock"
_HELD: dict[Path, int] = {}  # run directory -> file descriptor of its lock, for the locks this process holds


class RunDirBusyError(UserError):
    """Another live process writes the run directory."""


class DiskFullError(UserError):
    """A write that does not fit on its filesystem."""


class RunFileError(UserError):
    """A run's file that is missing, unreadable or damaged."""


def lock_run_dir(run_dir: str | os.PathLike, elsewhere: str = "give this run another directory") -> Path:
    """Make this process the one writer of ``run_dir`` (created if missing); idempotent. ``elsewhere``: how the
    user gives the command another directory, for the message of :class:`RunDirBusyError`."""
    d = Path(run_dir).resolve()
    if d in _HELD:
        return d
    d.mkdir(parents=True, exist_ok=True)
    while True:
        fd = os.open(d / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            if exc.errno not in (errno.EAGAIN, errno.EACCES):
                raise
            raise RunDirBusyError(
                f"{d} is being written by another process (pid {holder}); wait for it to end or stop it, or {elsewhere}"
            ) from None
        try:  # the file we locked may have been removed by its holder's release meanwhile: then lock the new one
            if os.stat(d / LOCK_NAME).st_ino == os.fstat(fd).st_ino:
                break
        except FileNotFoundError:
            pass
        os.close(fd)
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    _HELD[d] = fd
    return d


def unlock_run_dir(run_dir: str | os.PathLike, *, remove_if_empty: bool = False) -> None:
    """Release ``run_dir``'s lock and remove its file; ``remove_if_empty``: also the directory, if nothing else is in it."""
    d = Path(run_dir).resolve()
    fd = _HELD.pop(d, None)
    if fd is None:
        return
    with contextlib.suppress(OSError):
        (d / LOCK_NAME).unlink()  # while still locked: a process that opened it meanwhile sees the inode change
        if remove_if_empty:
            d.rmdir()
    os.close(fd)


@atexit.register
def _release_all() -> None:
    for d in list(_HELD):
        unlock_run_dir(d)


class OldRun:
    """The files of a run that a new one replaces (``overwrite=true``), moved into ``RUN_DIR/.replaced-<pid>``
    until the new run has started: :meth:`drop` removes them once it has, :meth:`restore` puts them back when it
    fails to start (a refused setting, a bad checkpoint), so a refused replacement loses nothing. A process killed
    in between leaves them in that folder. Falsy when there was no run to replace."""

    def __init__(self, run_dir: Path, names: list[str], found: list[str]):
        self.run_dir, self.names, self.found = run_dir, names, found
        self.folder = run_dir / f".replaced-{os.getpid()}"

    def __bool__(self) -> bool:
        return bool(self.found)

    def set_aside(self) -> None:
        self.folder.mkdir()
        for name in self.names:
            os.replace(self.run_dir / name, self.folder / name)

    def drop(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)
        self.names = []

    def restore(self) -> None:
        """Put the old run back, over whatever the failed start wrote at its files' names."""
        for name in self.names:
            new = self.run_dir / name
            if new.is_dir() and not new.is_symlink():
                shutil.rmtree(new)
            elif new.exists() or new.is_symlink():
                new.unlink()
            os.replace(self.folder / name, new)
        self.names = []
        with contextlib.suppress(OSError):
            self.folder.rmdir()


def clear_for_new_run(
    run_dir: Path, markers, overwrite: bool, *, error: type[Exception], options: str, also=()
) -> OldRun:
    """Refuse to start a new run in ``run_dir`` when it holds one (any of ``markers``: files, or non-empty folders),
    raising ``error`` with the user's ``options``, unless ``overwrite``: then that run's files (``markers`` and
    ``also``) and its TensorBoard folder are set aside (:class:`OldRun`), so the new run's record is not mixed with
    them; the caller drops them once the new run has started, or restores them."""
    run_dir = Path(run_dir)
    # an empty checkpoints/ is what a run that failed to start leaves: no run to protect
    found = [m for m in markers if (run_dir / m).is_file() or ((run_dir / m).is_dir() and any((run_dir / m).iterdir()))]
    if found and not overwrite:
        raise error(f"{run_dir} already holds a run ({', '.join(found)}); {options}, or replace it with overwrite=true")
    names = [m for m in dict.fromkeys((*markers, *also, "tb")) if (run_dir / m).exists() or (run_dir / m).is_symlink()]
    old = OldRun(run_dir, names if found else [], found)
    if found:
        old.set_aside()
    return old


def nbytes(obj) -> int:
    """The bytes of the tensors in ``obj`` (tensors, TensorDicts, dicts, lists, tuples, nested)."""
    import torch
    from tensordict import TensorDictBase

    if isinstance(obj, torch.Tensor):
        return obj.numel() * obj.element_size()
    if isinstance(obj, TensorDictBase):
        return sum(nbytes(v) for v in obj.values(True, True))
    if isinstance(obj, dict):
        return sum(nbytes(v) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return sum(nbytes(v) for v in obj)
    return 0


def _mib(n: float) -> str:
    return f"{n / 2**20:.1f} MiB"


def free_bytes(path: str | os.PathLike) -> int:
    """Free bytes on the filesystem that holds ``path`` (or its nearest existing parent)."""
    p = Path(path).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return shutil.disk_usage(p).free


# a filesystem allocates whole blocks per file, and small files (meta.json, CSV rows) come with every save
SLACK = 256 * 1024


def ensure_free(path: str | os.PathLike, need: int, what: str) -> None:
    """Raise :class:`DiskFullError` unless ``need`` bytes (plus a little slack) fit where ``path`` goes."""
    free = free_bytes(path)
    if need + SLACK > free:
        raise DiskFullError(
            f"not enough space to write {what} {path}: it needs about {_mib(need + SLACK)}, "
            f"{_mib(free)} are free; free some space there"
        )


@contextlib.contextmanager
def space_errors(path: str | os.PathLike, what: str):
    """Inside: ``ENOSPC``/``EDQUOT`` from a write becomes a one-line :class:`DiskFullError` naming ``path``.
    (``torch.save`` to an open file raises it, then a RuntimeError of its own while closing the archive.)"""
    try:
        yield
    except (OSError, RuntimeError) as exc:
        cause = exc
        while cause is not None and getattr(cause, "errno", None) not in (errno.ENOSPC, errno.EDQUOT):
            cause = cause.__context__
        if cause is None:
            raise
        raise DiskFullError(
            f"the disk filled while writing {what} {path} ({_mib(free_bytes(path))} free now); free some space there"
        ) from exc


def fsync_tree(path: str | os.PathLike) -> None:
    """Flush ``path`` (a file, or a folder with everything in it) to the disk, so that a rename or a ``COMPLETE``
    marker written after it never survives a machine crash (power, kernel) while the data it vouches for does not."""
    path = Path(path)
    for p in sorted(path.rglob("*"), reverse=True) if path.is_dir() else []:
        fsync_path(p)
    fsync_path(path)


def fsync_path(path: str | os.PathLike) -> None:
    """Flush one file, or one folder's entries (names made or renamed in it), to the disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def maze_run_message(run_dir: str | os.PathLike) -> str | None:
    """What to say when ``run_dir`` is a ``drs-maze`` run given to a command that reads drs-learn/drs-reuse runs
    (its saved config has ``map`` and ``dqn`` at the root, no ``env`` node); ``None`` for any other directory. (Read
    from the run's own ``config.yaml``: a run directory says what wrote it.)"""
    import yaml

    try:
        cfg = yaml.safe_load((Path(run_dir) / "config.yaml").read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return None
    if not (isinstance(cfg, dict) and "map" in cfg and "dqn" in cfg and "env" not in cfg):
        return None
    return (
        f"{run_dir} is a drs-maze run (the maze family's app, conf/maze.yaml), not a drs-learn/drs-reuse run: its "
        "evaluations are the eval_success column of its train.csv, and drs-maze phase=report "
        f"report.root={Path(run_dir).parent} report.out=DIR draws and tables maze runs"
    )


def load_run_config(run_dir: str | os.PathLike, needs: tuple[str, ...] = ("phase", "env", "reward", "algo")):
    """``RUN_DIR/config.yaml`` as an OmegaConf config, or a :class:`RunFileError` saying what is wrong with it
    (not YAML, or without the sections ``needs``), or an :class:`~drs_torchrl.runtime.safe_files.UnsafeFileError` when
    a ``_target_`` names code outside drs-torchrl, TorchRL, tensordict and torch."""
    import yaml
    from omegaconf import DictConfig, OmegaConf

    path = Path(run_dir) / "config.yaml"
    record = Path(run_dir) / ".hydra" / "config.yaml"
    fix = (
        f"restore it (the run's Hydra record {record} holds the config it started with, its values unresolved)"
        if record.is_file()
        else "restore it from a copy"
    )
    try:
        cfg = OmegaConf.load(path)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise RunFileError(
            f"{path} is damaged (not valid YAML{f' at line {mark.line + 1}' if mark else ''}); {fix}"
        ) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise RunFileError(f"{path} cannot be read ({exc.__class__.__name__}: {exc}); {fix}") from None
    missing = [k for k in needs if not isinstance(cfg, DictConfig) or k not in cfg]
    if missing:
        raise RunFileError(maze_run_message(run_dir) or f"{path} is damaged: it lacks {', '.join(missing)}; {fix}")
    from drs_torchrl.runtime.safe_files import check_targets

    check_targets(cfg, path)  # resuming or evaluating instantiates what it names
    return cfg


def check_writable(path: str | os.PathLike, what: str, *, folder: bool = False) -> Path:
    """``path`` as a :class:`Path` if a file (``folder=False``) or folder can be written there, else a
    :class:`UserError` naming it (a file in the way, a folder where a file is wanted, no permission)."""
    p = Path(path)
    kind = "folder" if folder else "file"
    if p.exists():
        if folder and not p.is_dir():
            raise UserError(f"{what} {p} is a file, not a folder; give a folder (it is made if missing)")
        if not folder and p.is_dir():
            raise UserError(f"{what} {p} is a folder; give a file name")
        if not os.access(p, os.W_OK):
            raise UserError(f"{what} {p} cannot be written (no permission); give another {kind}")
        return p
    parent = p.absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise UserError(f"{what} {p} cannot be made: {parent} is a file, not a folder; give another {kind}")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UserError(f"{what} {p} cannot be made: {parent} is not writable; give another {kind}")
    return p


def read_run_csv(path: str | os.PathLike):
    """A run's ``train.csv`` / ``eval.csv`` as a DataFrame, or a :class:`RunFileError` naming the damaged file."""
    import pandas as pd

    try:
        return pd.read_csv(path)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, ValueError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise RunFileError(
            f"{path} is damaged (not a readable CSV: {first}); restore it from the run's record, or leave this run out"
        ) from None
