"""A run's checkpoints: the user-facing files (``reward.pt``, ``policy.pt``) and the training state.

The training state (``checkpoints/state``) is everything a run needs to continue: ``trainer.pt`` (the loop's
counters, the updater's networks and optimisers, the reward learner's state, RNG states, recent episodes) and the
buffers (memory-mapped TensorDicts of their filled slots). A new state is written beside the old one and swapped
in by renames, so a crash while writing leaves the previous state usable; SIGINT/SIGTERM arriving meanwhile are
delivered after; the bytes are checked against the free space first (memory-mapped buffers on a full disk die of
SIGBUS instead of raising). Own code: ``torchrl.checkpoint`` saves one object per call and has no atomic
swap, free-space check or signal deferral.
"""

from __future__ import annotations

import os
import random
import shutil
from pathlib import Path

import numpy as np
import torch
from torchrl.data import ReplayBuffer

from drs_torchrl.data.persistence import SnapshotError, buffer_bytes, dump_buffer, load_buffer
from drs_torchrl.runtime.errors import UserError
from drs_torchrl.runtime.safe_files import UnsafeFileError, torch_load
from drs_torchrl.runtime.rundir import ensure_free, fsync_path, fsync_tree, nbytes, space_errors
from drs_torchrl.runtime.signals import signals_deferred

STATE_FORMAT = "drs-torchrl/training-state"
STATE_VERSION = 1


class TrainingStateError(UserError, RuntimeError):
    """A run directory whose training state cannot be resumed."""


def find_training_state(run_dir: Path) -> Path:
    """The newest complete training state of ``run_dir`` (``state``, else ``state.old``)."""
    ck = Path(run_dir) / "checkpoints"
    for name in ("state", "state.old"):
        if (ck / name / "COMPLETE").is_file():
            return ck / name
    if not Path(run_dir).is_dir():
        raise TrainingStateError(f"cannot resume: {run_dir} does not exist")
    raise TrainingStateError(
        f"cannot resume: {run_dir} has no complete training state in checkpoints/ (a run saves one every "
        "checkpoint_interval env steps and when it is interrupted)"
    )


def atomic_torch_save(obj, path: Path) -> None:
    """``torch.save`` into a temporary file renamed over ``path``: ``path`` is the old file or the new one,
    never a part (a full disk raises :class:`~drs_torchrl.runtime.rundir.DiskFullError` and leaves the old one)."""
    _atomic_write(path, lambda f: torch.save(obj, f), "wb")


def atomic_write_text(path: Path, text: str) -> None:
    _atomic_write(path, lambda f: f.write(text), "w")


def _atomic_write(path: Path, write, mode: str) -> None:
    tmp = path.with_name(path.name + f".tmp-{os.getpid()}")
    try:
        with space_errors(path, "the file"), open(tmp, mode) as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())  # on the disk before it takes the name (a machine crash keeps old or new)
        os.replace(tmp, path)
        fsync_path(path.parent)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def rng_state() -> dict:
    """The RNG states as tensors, numbers and strings (numpy's key array as an int64 tensor), which a weights-only
    load reads."""
    name, keys, pos, has_gauss, cached = np.random.get_state()
    numpy_state = {"name": name, "keys": torch.from_numpy(keys.astype(np.int64)), "pos": int(pos)}
    numpy_state.update(has_gauss=int(has_gauss), cached_gaussian=float(cached))
    return {"torch": torch.get_rng_state(), "numpy": numpy_state, "python": random.getstate()}


def set_rng_state(state: dict) -> None:
    torch.set_rng_state(state["torch"])
    n = state["numpy"]
    if not isinstance(n, dict):  # numpy's own tuple: a state of an earlier version, converted by drs-convert
        n = dict(zip(("name", "keys", "pos", "has_gauss", "cached_gaussian"), n))
    keys = np.asarray(torch.as_tensor(n["keys"]).numpy(), dtype=np.uint32)
    np.random.set_state((n["name"], keys, int(n["pos"]), int(n["has_gauss"]), float(n["cached_gaussian"])))
    random.setstate(state["python"])


class Checkpointer:
    """Writes and reads ``RUN_DIR/checkpoints``.

    Args:
        run_dir: the run directory.
        buffers: the replay buffers of the training state by name (``{"replay": rb}``; an on-policy run: none).
        learner: the reward learner, whose buffers (stage buffers, classifier data) it dumps itself.
    """

    def __init__(self, run_dir: str | Path, buffers: dict[str, ReplayBuffer] | None = None, learner=None):
        self.dir = Path(run_dir) / "checkpoints"
        self.dir.mkdir(parents=True, exist_ok=True)
        self.buffers = dict(buffers or {})
        self.learner = learner

    # ------------------------------------------------------------------ user-facing files
    def check_room(self, objects, state_payload: dict) -> None:
        """Room for ``objects`` and the training state written after them, checked before writing any: a run never
        holds checkpoints newer than its state."""
        need = sum(nbytes(o) for o in objects) + self.state_bytes(state_payload)
        ensure_free(self.dir, need, "the checkpoints and training state in")

    def save_files(self, files: dict[str, object]) -> dict[str, str]:
        """``{name: torch object}`` as ``checkpoints/<name>.pt``, each atomically."""
        paths = {}
        for name, obj in files.items():
            atomic_torch_save(obj, self.dir / f"{name}.pt")
            paths[name] = str(self.dir / f"{name}.pt")
        return paths

    # ------------------------------------------------------------------ training state
    def state_bytes(self, payload: dict) -> int:
        """About the bytes the training state takes on disk: ``payload``'s tensors and the buffers' filled slots."""
        learner = [b for b in vars(self.learner).values() if isinstance(b, ReplayBuffer)] if self.learner else []
        unique = {id(b): b for b in [*self.buffers.values(), *learner]}
        return nbytes(payload) + sum(buffer_bytes(b) for b in unique.values())

    def save_state(self, payload: dict) -> Path:
        """``payload`` (``trainer.pt``) and the buffers, written atomically to ``checkpoints/state``."""
        with signals_deferred():
            return self._write_state(payload)

    def _write_state(self, payload: dict) -> Path:
        ck = self.dir
        final, tmp, old = ck / "state", ck / f"state.tmp-{os.getpid()}", ck / "state.old"
        for stale in ck.glob("state.tmp-*"):  # left by a process killed while saving
            shutil.rmtree(stale, ignore_errors=True)
        if (final / "COMPLETE").is_file():
            shutil.rmtree(old, ignore_errors=True)  # a fallback left by a crash while swapping: state is newer
        payload = {"format": STATE_FORMAT, "version": STATE_VERSION, **payload}
        ensure_free(ck, self.state_bytes(payload), "the training state in")
        try:
            with space_errors(tmp, "the training state"):
                tmp.mkdir(parents=True)
                for name, buffer in self.buffers.items():
                    dump_buffer(buffer, tmp / name)
                if self.learner is not None:
                    self.learner.dump_buffers(tmp)
                with open(tmp / "trainer.pt", "wb") as f:  # an open file: a full disk raises ENOSPC
                    torch.save(payload, f)
                fsync_tree(tmp)  # everything on the disk before COMPLETE vouches for it
                (tmp / "COMPLETE").write_text(str(payload.get("counters", {}).get("frames", "")))
                fsync_path(tmp / "COMPLETE")
                fsync_path(tmp)  # the marker's name too
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)  # the last complete state stays as it was
            raise
        # swap in: at every instant one complete state exists (final, else old)
        if (final / "COMPLETE").is_file():
            shutil.rmtree(old, ignore_errors=True)
            final.rename(old)
        elif final.exists():
            shutil.rmtree(final)  # a partial state left by a crash; old (if any) stays the fallback
        tmp.rename(final)
        fsync_path(ck)  # the renames on the disk before the fallback goes
        shutil.rmtree(old, ignore_errors=True)
        return final

    def read_state(self, phase: str) -> tuple[dict, Path]:
        """``(payload, state directory)`` of the newest complete state, checked for its format and phase."""
        state_dir = find_training_state(self.dir.parent)
        try:
            payload = torch_load(state_dir / "trainer.pt", "training state")
        except UnsafeFileError:
            raise
        except Exception as exc:
            why = str(exc).split(". ")[0].split("\n")[0]
            raise TrainingStateError(
                f"{state_dir / 'trainer.pt'} cannot be read (corrupt or truncated: {why}); the run cannot "
                "continue from it: start it afresh with overwrite=true (its checkpoints/reward.pt and "
                "policy.pt are separate files: copy them first to keep them)"
            ) from exc
        if payload.get("format") != STATE_FORMAT or int(payload.get("version", 99)) > STATE_VERSION:
            raise TrainingStateError(f"{state_dir} was not written by this version of drs-torchrl")
        if payload["phase"] != phase:
            raise TrainingStateError(
                f"{self.dir.parent} is a drs-{payload['phase']} run; resume it with drs-{payload['phase']}"
            )
        return payload, state_dir

    # ------------------------------------------------------------------ the loop's state (drs-learn, drs-maze)
    def loop_state(self, phase: str, updater, progress, episodes, **counters) -> dict:
        """The training state apart from the buffers (``trainer.pt``): the updater's networks and optimisers, the
        loop's counters (:class:`~drs_torchrl.loop.Progress` and the caller's ``counters``), the reward learner's state,
        the recent episodes and the RNG states."""
        u = updater.state_dict()
        return {
            "phase": phase,
            "algo": updater.name,
            "counters": {
                "frames": progress.frames,
                "updates": u.pop("updates"),
                "disc_updates": self.learner.updates if self.learner is not None else 0,
                "owed_updates": u.pop("owed_updates"),
                "last_eval_frames": progress.last_eval_frames,
                "eval_streak": progress.eval_streak,
                **counters,
            },
            **u,  # loss, optimizers (and whatever else the updater keeps)
            "learner": self.learner.state_dict() if self.learner is not None else None,
            "recent_episodes": list(episodes.recent),
            "rng": rng_state(),
        }

    def restore_loop_state(self, phase: str, updater, progress, episodes) -> dict:
        """Everything :meth:`loop_state` and the buffers hold, back from the newest complete state into ``updater``,
        ``progress``, ``episodes``, the learner and the RNGs; returns the saved counters."""
        run_dir = self.dir.parent
        payload, state_dir = self.read_state(phase)
        if "algo" not in payload or "learner" not in payload:  # written by the code before 0.1.0, never released
            raise TrainingStateError(
                f"{run_dir}'s training state predates drs-torchrl 0.1.0 (no algorithm or reward learner recorded) "
                "and cannot be resumed: start a new run (its checkpoints/reward.pt and policy.pt still load)"
            )
        if payload["algo"] != updater.name:
            raise TrainingStateError(
                f"{run_dir}'s training state is {payload['algo']}'s, this run trains {updater.name}"
            )
        c = payload["counters"]
        progress.frames, progress.last_eval_frames = int(c["frames"]), int(c["last_eval_frames"])
        progress.eval_streak = int(c.get("eval_streak", 0))  # states written before it was kept: none
        progress.resumed_from = progress.frames
        known = ("format", "version", "phase", "algo", "counters", "learner", "recent_episodes", "rng")
        state = {k: v for k, v in payload.items() if k not in known}
        updater.load_state_dict({**state, "updates": c["updates"], "owed_updates": c["owed_updates"]})
        self.restore_buffers(state_dir, payload["learner"])
        episodes.recent.extend(tuple(e) for e in payload["recent_episodes"])
        set_rng_state(payload["rng"])
        return c

    def restore_buffers(self, state_dir: Path, learner_state: dict | None) -> None:
        """The learner's state and every buffer from ``state_dir``; a damaged part raises :class:`TrainingStateError`."""
        try:
            if self.learner is not None:
                self.learner.load_state_dict(learner_state)
                self.learner.load_buffers(state_dir)
            for name, buffer in self.buffers.items():
                load_buffer(buffer, state_dir / name)
        except (SnapshotError, OSError, KeyError, RuntimeError) as exc:
            raise TrainingStateError(f"the training state in {state_dir} is damaged: {exc}") from exc
