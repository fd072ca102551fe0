"""Files from elsewhere run no code: every ``torch.load`` of the project is weights-only, every memory-mapped
TensorDict is read without its pickle sidecar, and a run's ``config.yaml`` may only name the library's, TorchRL's and
torch's classes and functions.

Rewards, policies and run directories are made to be shared, and a full unpickling runs whatever a file pickled.
drs-torchrl writes only tensors, numbers, strings and plain containers, which a weights-only load reads; a file that
needs more is refused with one line naming what it holds. A file of an earlier version (its numpy RNG state, an
``ndarray``) is rewritten by ``drs-convert``, which reads it weights-only as well, with numpy's array constructors
allowed.
"""

from __future__ import annotations

import argparse
import os
import pickle
import re
import shutil
import sys
from pathlib import Path

import torch

from drs_torchrl.runtime.errors import UserError

#: what a run's config may instantiate (``_target_``) on resume and evaluation: the modules whose classes and
#: functions the configs build (the project's library, TorchRL's losses, buffers, collectors, modules and transforms,
#: torch's optimisers and layers), never a name with a loader in it (``torch.load``-like calls read pickles) or a
#: private one; anything else is refused
ALLOWED_TARGETS = (
    *(f"drs_torchrl.{m}." for m in ("rewards", "updaters", "learners", "objectives", "transforms", "models", "data")),
    *(f"torchrl.{m}." for m in ("objectives", "data", "collectors", "modules", "envs.transforms")),
    "torch.optim.",
    "torch.nn.",
)
CONVERT = "drs-convert"


class UnsafeFileError(UserError, ValueError):
    """A file that would need to run code to be read (a pickled object beyond tensors and plain containers)."""


def _unsafe_globals(exc: BaseException) -> list[str]:
    return sorted(set(re.findall(r"GLOBAL ([\w.]+)", str(exc))))


def torch_load(path: str | Path, what: str, map_location="cpu"):
    """``torch.load(path, weights_only=True)``; a file holding anything else raises :class:`UnsafeFileError`
    (one line: the file, what it holds, why it is not loaded, and ``drs-convert`` for a file of an earlier version).
    Other read errors (missing, truncated, not a torch file) propagate for the caller to word."""
    try:
        return torch.load(path, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as exc:
        found = _unsafe_globals(exc) or ["a pickled object"]
        raise UnsafeFileError(
            f"{path}: refused: this {what} holds {', '.join(found)}, which only a full unpickling would load, and "
            "unpickling runs whatever the file names (drs-torchrl writes tensors, numbers and strings only); a "
            f"file of an earlier drs-torchrl (numpy arrays in it) is rewritten in the safe form by: {CONVERT} {path}"
        ) from None


#: the user's own modules a run's config may name too (a reward builder of theirs, docs/rewards.md): comma-separated
#: prefixes in this environment variable, which a file from elsewhere cannot set
TRUSTED_ENV = "DRS_TRUSTED_TARGETS"


def _trusted() -> tuple[str, ...]:
    own = tuple(p.strip().rstrip(".") + "." for p in os.environ.get(TRUSTED_ENV, "").split(",") if p.strip())
    return ALLOWED_TARGETS + own


def allowed_target(value) -> bool:
    """A ``_target_`` a config from elsewhere may name: a plain dotted name under :data:`ALLOWED_TARGETS` (or a prefix
    the user trusts in ``$DRS_TRUSTED_TARGETS``), none of whose parts is private or a loader."""
    if not isinstance(value, str) or not re.fullmatch(r"[A-Za-z_][\w.]*", value) or not value.startswith(_trusted()):
        return False
    return not any(part.startswith("_") or "load" in part.lower() for part in value.split("."))


def check_targets(cfg, source: str | Path) -> None:
    """Refuse a config (OmegaConf or plain container) whose ``_target_`` names anything outside
    :data:`ALLOWED_TARGETS` or is not a plain string: ``source`` is named in the one-line message."""
    from omegaconf import OmegaConf

    tree = OmegaConf.to_container(cfg, resolve=False) if OmegaConf.is_config(cfg) else cfg

    def walk(node, path: str) -> None:
        if isinstance(node, dict):
            for key, value in node.items():
                where = f"{path}.{key}" if path else str(key)
                if key == "_target_" and not allowed_target(value):
                    raise UnsafeFileError(
                        f"{source}: refused: {where} is {value!r}; a run's config may instantiate only the classes and "
                        f"functions of {', '.join(p.rstrip('.') for p in ALLOWED_TARGETS)}, no loader (a config from "
                        f"elsewhere must not run other code); for a module of your own: {TRUSTED_ENV}=your_module"
                    )
                walk(value, where)
        elif isinstance(node, list):
            for i, value in enumerate(node):
                walk(value, f"{path}[{i}]")

    walk(tree, "")


# ---------------------------------------------------------------------------------------------- conversion
def _plain(obj):
    """``obj`` with numpy arrays and scalars as tensors and numbers (the only non-plain values earlier versions
    wrote: the numpy RNG state); anything else that is not plain raises :class:`UnsafeFileError`."""
    import numpy as np

    if isinstance(obj, np.ndarray):
        if obj.dtype == object:
            raise UnsafeFileError("it holds a numpy object array, which drs-torchrl never wrote")
        return torch.from_numpy(obj.astype(np.int64) if obj.dtype == np.uint32 else obj.copy())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        out = [_plain(v) for v in obj]
        return tuple(out) if isinstance(obj, tuple) else out
    if obj is None or isinstance(obj, (bool, int, float, str, bytes, torch.Tensor, torch.dtype, torch.Size)):
        return obj
    raise UnsafeFileError(f"it holds a {type(obj).__module__}.{type(obj).__qualname__}, which drs-torchrl never wrote")


def _numpy_globals() -> list:
    """The numpy constructors earlier versions' files need (the RNG state's ``ndarray``, numpy scalars): they build
    arrays and numbers, nothing else."""
    import numpy as np

    core = np.core.multiarray
    dtypes = [getattr(np.dtypes, n) for n in dir(np.dtypes) if n.endswith("DType")] if hasattr(np, "dtypes") else []
    return [core._reconstruct, core.scalar, np.ndarray, np.dtype, *dtypes]


def convert_file(path: str | Path) -> Path | None:
    """Rewrite a torch file of an earlier drs-torchrl (numpy arrays and scalars in it) in the weights-only form,
    keeping the original as ``<file>.orig``; returns the kept original, or None when the file already loads safely
    (left as it is). It reads the file weights-only too, allowing numpy's array constructors: nothing in it runs, and
    a file that needs more is refused."""
    path = Path(path)
    if not path.is_file():
        raise UnsafeFileError(f"{path}: no such file")
    try:
        torch.load(path, map_location="cpu", weights_only=True)
        return None
    except pickle.UnpicklingError:
        pass
    try:  # still weights-only: numpy's array and scalar constructors are the only globals added
        with torch.serialization.safe_globals(_numpy_globals()):
            obj = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        found = ", ".join(_unsafe_globals(exc)) or "a pickled object"
        raise UnsafeFileError(f"{path}: not converted: it holds {found}, which drs-torchrl never wrote") from None
    try:
        plain = _plain(obj)
    except UnsafeFileError as exc:
        raise UnsafeFileError(f"{path}: not converted: {exc}") from None
    from drs_torchrl.runtime.checkpoint import atomic_torch_save

    kept = path.with_name(path.name + ".orig")
    shutil.copy2(path, kept)
    atomic_torch_save(plain, path)
    torch.load(path, map_location="cpu", weights_only=True)  # the point of it
    return kept


def _files(target: Path) -> list[Path]:
    if target.is_dir():  # a run directory: its checkpoints and training states
        return sorted(p for p in target.rglob("*.pt") if ".orig" not in p.name)
    return [target]


def main(argv: list[str] | None = None) -> int:
    from drs_torchrl.runtime.console import console_script

    @console_script(CONVERT)
    def run(argv):
        parser = argparse.ArgumentParser(
            prog=CONVERT,
            description="Rewrite torch files written by an earlier drs-torchrl (numpy arrays in them) so that "
            "drs-torchrl's weights-only loading reads them; the original is kept as FILE.orig. It reads them "
            "weights-only too (numpy's array constructors allowed): a file that would run code is refused.",
        )
        parser.add_argument("paths", nargs="+", help="a .pt file, or a run directory (all its .pt files)")
        a = parser.parse_args(argv)
        for target in map(Path, a.paths):
            if not target.exists():
                raise UnsafeFileError(f"{target}: no such file or directory")
            for f in _files(target):
                kept = convert_file(f)
                print(f"{f}: " + ("already safe, unchanged" if kept is None else f"converted (original: {kept})"))
        return 0

    return run(argv if argv is not None else sys.argv[1:])


if __name__ == "__main__":
    sys.exit(main())
