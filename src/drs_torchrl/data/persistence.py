"""Compact on-disk snapshots of replay buffers (for resuming runs).

TorchRL's ``ReplayBuffer.dumps`` writes a lazily allocated storage at its full capacity (a 2M-slot
buffer holding 1k transitions takes over a gigabyte). :func:`dump_buffer` writes only the filled
slots, oldest first, as a memory-mapped TensorDict (one file per entry, nothing loaded whole in
memory to write it); :func:`load_buffer` refills an empty buffer of the same layout from it, so the
restored buffer holds the same transitions in the same age order and overwrites the oldest first.
It checks the free space first: a memory map written past the end of a full disk faults (SIGBUS).
"""

from __future__ import annotations

import json
from pathlib import Path

import torch
from tensordict import TensorDict
from torchrl.data import ReplayBuffer

from drs_torchrl.runtime.console import UserError
from drs_torchrl.runtime.rundir import ensure_free, nbytes
from drs_torchrl.runtime.safe_files import UnsafeFileError, torch_load


class SnapshotError(UserError, ValueError):
    """An on-disk TensorDict whose files are missing, truncated or not a TensorDict at all."""


def load_memmap_checked(path: str | Path) -> TensorDict:
    """``TensorDict.load_memmap`` after checking every file against its recorded shape and dtype.

    ``load_memmap`` silently zero-fills a truncated file; a damaged snapshot must fail instead.
    Nested TensorDicts (sub-directories with their own ``meta.json``) are checked recursively.
    """
    path = Path(path)
    _check_memmap_dir(path)
    try:
        return TensorDict.load_memmap(path, allow_pickle=False)  # a pickle sidecar would run code
    except RuntimeError as exc:
        if "pickle" not in str(exc).lower():
            raise
        raise UnsafeFileError(
            f"{path}: refused: this saved TensorDict holds pickled Python objects, and unpickling runs whatever the "
            "file names (drs-torchrl saves tensors only)"
        ) from None


def _check_memmap_dir(path: Path) -> None:
    meta_path = path / "meta.json"
    if not meta_path.is_file():
        raise SnapshotError(f"{path} is not a saved TensorDict (no meta.json)")
    try:
        meta = json.loads(meta_path.read_text())
    except json.JSONDecodeError as exc:
        raise SnapshotError(f"{meta_path} is corrupt: {exc}") from exc
    for key, info in meta.items():
        if not isinstance(info, dict) or "shape" not in info or "dtype" not in info:
            continue
        f = path / f"{key}.memmap"
        dtype = getattr(torch, str(info["dtype"]).replace("torch.", ""))
        expected = int(torch.Size(info["shape"]).numel()) * torch.empty((), dtype=dtype).element_size()
        have = f.stat().st_size if f.is_file() else -1
        if have != expected:
            raise SnapshotError(f"{f} holds {max(have, 0)} bytes where {expected} are expected (truncated or missing)")
    for sub in path.iterdir():
        if sub.is_dir() and (sub / "meta.json").is_file():
            _check_memmap_dir(sub)


def _filled(rb: ReplayBuffer):
    """The filled slots of ``rb``'s storage, oldest first, in the layout ``extend`` takes: a storage with a time
    dimension (``LazyTensorStorage(ndim=2)``, which holds ``(T, envs)`` and is extended with ``(envs, T)``) is cut along
    time and transposed back."""
    if hasattr(rb, "snapshot_parts"):  # StageBuffers: one FIFO ring per stage
        return rb.snapshot_parts()
    storage = rb.storage
    n = len(storage)
    if n == 0:
        return []
    data = storage._storage  # the TensorDict behind LazyTensorStorage / LazyMemmapStorage
    rows = data.shape[0]  # slots along the storage's first dimension (time, for ndim=2)
    filled = n // (data[0].numel() if storage.ndim > 1 else 1)
    cursor = int(getattr(rb._writer, "_cursor", filled)) % rows
    parts = [data[:filled]] if filled < rows or cursor == 0 else [data[cursor:], data[:cursor]]  # wrapped: oldest first
    if storage.ndim > 1:
        parts = [p.transpose(0, 1).contiguous() for p in parts]
    return parts


def buffer_bytes(rb: ReplayBuffer) -> int:
    """The bytes :func:`dump_buffer` writes for ``rb`` (its filled slots)."""
    return sum(nbytes(p) for p in _filled(rb))


def dump_buffer(rb: ReplayBuffer, path: str | Path) -> dict:
    path = Path(path)
    parts = _filled(rb)
    ensure_free(path, sum(nbytes(p) for p in parts), "the buffer snapshot")
    path.mkdir(parents=True, exist_ok=True)
    for i, part in enumerate(parts):
        part.memmap(path / f"part{i}", num_threads=0)
    meta = {
        "parts": len(parts),
        "len": len(rb),
        "capacity": rb.storage.max_size,
        "write_count": int(getattr(rb._writer, "_write_count", len(rb))),
    }
    (path / "meta.json").write_text(json.dumps(meta))
    sampler_state = rb._sampler.state_dict() if hasattr(rb._sampler, "state_dict") else {}
    if sampler_state and not hasattr(rb._sampler, "num_stages"):  # StageSampler is rebuilt by extend
        torch.save(sampler_state, path / "sampler.pt")
    return meta


def load_buffer(rb: ReplayBuffer, path: str | Path) -> dict:
    path = Path(path)
    try:
        meta = json.loads((path / "meta.json").read_text())
    except (OSError, ValueError) as exc:
        raise SnapshotError(f"{path / 'meta.json'} cannot be read (missing or corrupt): {exc}") from exc
    if len(rb):
        raise ValueError("load_buffer needs an empty buffer")
    if meta["len"] > rb.storage.max_size:
        raise ValueError(
            f"the saved buffer holds {meta['len']} transitions, more than this buffer's capacity {rb.storage.max_size}"
        )
    for i in range(meta["parts"]):
        part = load_memmap_checked(path / f"part{i}")  # copied page by page from the memory map
        if hasattr(rb, "snapshot_parts"):
            rb.extend(part)  # StageBuffers files each transition by its stage
        else:  # the stored form: past the buffer's inverse transforms (n-step windows were formed when it was stored)
            rb._extend(part)
    if (path / "sampler.pt").is_file():
        rb._sampler.load_state_dict(torch_load(path / "sampler.pt", "replay sampler state"))
    return meta
