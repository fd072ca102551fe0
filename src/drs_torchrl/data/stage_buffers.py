"""Stage buffers (Sec. 4.2-4.3, Algorithm 1 lines 2-3 and 7-15) as a TorchRL replay buffer.

Every finished trajectory is filed by its stage index ``max_t stage(s_t)`` (Eq. 3). The stage
buffers ``B_0..B_N`` share one storage, in which :class:`StageRingWriter` gives each stage its own
FIFO ring (so common failures never evict rare successes or demonstrations, and a full success
buffer forgets its oldest successes, as with the authors' separate buffers). :class:`StageSampler`
keeps, per stage, the storage slots that belong to it and draws, for discriminator ``k``, positives
from stages ``> k`` and negatives from stages ``<= k``, each uniformly over the union (hence across
stages in proportion to their sizes).

Filing rules (the authors' public implementation): a failed trajectory (top stage ``j < N``) is cut
right after the last step at which it was at stage ``j``; a successful one and every demonstration
go whole into the top buffer ``N``.
"""

from __future__ import annotations

import shutil
import tempfile
import weakref
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.data import LazyMemmapStorage, LazyTensorStorage, ReplayBuffer
from torchrl.data.replay_buffers import Sampler, Writer
from drs_torchrl.runtime.safe_files import torch_load

TRAJ_STAGE_KEY = "traj_stage"


def trajectory_stage(stages: torch.Tensor) -> int:
    """Eq. 3: the stage index of a trajectory is the highest stage index of its states."""
    return int(stages.max())


def truncate_failed(stages: torch.Tensor, num_stages: int) -> int:
    """Length to keep of a trajectory with per-step stages ``stages`` (shape ``(T,)``).

    Successful trajectories (top stage ``N``) are kept whole; failed ones are cut right after the
    last step at which they were at their highest stage.
    """
    stages = stages.reshape(-1)
    top = int(stages.max())
    if top >= num_stages:
        return int(stages.numel())
    last = int((stages == top).nonzero().max())
    return last + 1


class StageSampler(Sampler):
    """Draws discriminator training batches from stage buffers sharing one storage.

    ``sample(storage, batch_size)`` returns ``N * 2 * batch_size`` storage indices ordered as
    ``(k, label, b)``: for each discriminator ``k = 0..N-1``, ``batch_size`` negatives (trajectory
    stage ``<= k``) then ``batch_size`` positives (stage ``> k``), each uniform over the union of its
    stage buffers. A side with no data yields index ``-1``-free placeholders and ``info["valid"][k]``
    is ``False``; the loss then skips that discriminator.

    Stage labels are read from the storage entry ``stage_key`` of newly written slots the next time
    it samples, so the work per call is proportional to what was added, not to the buffer size.
    Overwritten slots (a full storage) move out of their old stage.
    """

    def __init__(self, num_stages: int, stage_key: str = TRAJ_STAGE_KEY):
        self.num_stages = int(num_stages)
        self.stage_key = stage_key
        self._empty()

    # --------------------------------------------------------------- bookkeeping
    def _empty(self):
        self._lists = [np.empty(0, dtype=np.int64) for _ in range(self.num_stages + 1)]
        self._counts = np.zeros(self.num_stages + 1, dtype=np.int64)
        self._slot_stage = np.empty(0, dtype=np.int64)  # slot -> stage (-1 empty)
        self._slot_pos = np.empty(0, dtype=np.int64)  # slot -> position in its stage list
        self._pending: list[torch.Tensor] = []

    def extend(self, index: torch.Tensor) -> None:
        self._pending.append(torch.as_tensor(index).reshape(-1).clone())

    def add(self, index: int) -> None:
        self.extend(torch.as_tensor([index]))

    def _grow_slots(self, n: int):
        if n > self._slot_stage.size:
            size = max(n, 2 * self._slot_stage.size, 1024)
            self._slot_stage = np.concatenate([self._slot_stage, np.full(size - self._slot_stage.size, -1, np.int64)])
            self._slot_pos = np.concatenate([self._slot_pos, np.full(size - self._slot_pos.size, -1, np.int64)])

    def _remove(self, slot: int):
        s, p = self._slot_stage[slot], self._slot_pos[slot]
        last = self._counts[s] - 1
        moved = self._lists[s][last]
        self._lists[s][p] = moved
        self._slot_pos[moved] = p
        self._counts[s] = last
        self._slot_stage[slot] = -1

    def _append(self, stage: int, slots: np.ndarray):
        lst, c = self._lists[stage], self._counts[stage]
        if c + slots.size > lst.size:
            new = np.empty(max(c + slots.size, 2 * lst.size, 1024), np.int64)
            new[:c] = lst[:c]
            self._lists[stage] = lst = new
        lst[c : c + slots.size] = slots
        self._slot_stage[slots] = stage
        self._slot_pos[slots] = np.arange(c, c + slots.size)
        self._counts[stage] = c + slots.size

    def sync(self, storage) -> None:
        """File slots written since the last call by reading their stage label from ``storage``."""
        if not self._pending:
            return
        slots = torch.cat(self._pending)
        self._pending = []
        stages = storage.get(slots).get(self.stage_key).reshape(-1).cpu().numpy().astype(np.int64)
        slots = slots.cpu().numpy().astype(np.int64)
        if stages.min() < 0 or stages.max() > self.num_stages:
            raise ValueError(f"stage labels must lie in [0, {self.num_stages}], got {stages.min()}..{stages.max()}")
        self._grow_slots(int(slots.max()) + 1)
        # the same slot may appear twice in one sync (overwritten twice): keep its last label
        _, last_idx = np.unique(slots[::-1], return_index=True)
        keep = np.sort(slots.size - 1 - last_idx)
        slots, stages = slots[keep], stages[keep]
        for slot in slots[self._slot_stage[slots] >= 0]:
            self._remove(int(slot))
        for s in np.unique(stages):
            self._append(int(s), slots[stages == s])

    def stage_counts(self, storage=None) -> np.ndarray:
        """Number of transitions filed under each trajectory stage ``0..N``."""
        if storage is not None:
            self.sync(storage)
        return self._counts.copy()

    def valid_discriminators(self, storage=None) -> np.ndarray:
        """Which discriminators have both negatives (stage <= k) and positives (stage > k)."""
        c = self.stage_counts(storage)
        cum = np.cumsum(c)
        neg = cum[:-1]
        pos = cum[-1] - neg
        return (neg > 0) & (pos > 0)

    # ---------------------------------------------------------------- sampling
    def _draw(self, stages: range, n: int) -> torch.Tensor:
        counts = self._counts[list(stages)]
        total = int(counts.sum())
        if total == 0:  # placeholder for an invalid side: any filed slot (never unwritten memory)
            filled = next(lst for lst, c in zip(self._lists, self._counts) if c > 0)
            return torch.full((n,), int(filled[0]), dtype=torch.long)
        r = torch.randint(total, (n,), generator=self._rng).numpy()
        cum = np.cumsum(counts)
        which = np.searchsorted(cum, r, side="right")
        offset = r - (cum - counts)[which]
        out = np.empty(n, np.int64)
        for w in np.unique(which):
            m = which == w
            out[m] = self._lists[stages[w]][offset[m]]
        return torch.from_numpy(out)

    def sample(self, storage, batch_size: int) -> tuple[torch.Tensor, dict]:
        self.sync(storage)
        if len(storage) == 0:
            raise RuntimeError("the stage buffers are empty: add trajectories before sampling")
        N = self.num_stages
        idx = torch.empty(N, 2, batch_size, dtype=torch.long)
        for k in range(N):
            idx[k, 0] = self._draw(range(0, k + 1), batch_size)
            idx[k, 1] = self._draw(range(k + 1, N + 1), batch_size)
        return idx.reshape(-1), {"valid": torch.from_numpy(self.valid_discriminators())}

    # ------------------------------------------------------------ persistence
    def state_dict(self) -> dict[str, Any]:
        return {
            "num_stages": self.num_stages,
            "lists": [torch.from_numpy(lst[:c].copy()) for lst, c in zip(self._lists, self._counts)],
            "pending": [p.clone() for p in self._pending],
        }

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        if int(state_dict["num_stages"]) != self.num_stages:
            raise ValueError(f"sampler state has {state_dict['num_stages']} stages, this sampler {self.num_stages}")
        self._empty()
        lists = [np.asarray(t, dtype=np.int64) for t in state_dict["lists"]]
        n = max([int(lst.max()) + 1 for lst in lists if lst.size] or [0])
        self._grow_slots(n)
        for s, lst in enumerate(lists):
            if lst.size:
                self._append(s, lst)
        self._pending = [torch.as_tensor(p) for p in state_dict.get("pending", [])]

    def dumps(self, path):
        path = Path(path)
        path.mkdir(parents=True, exist_ok=True)
        torch.save(self.state_dict(), path / "stage_sampler.pt")

    def loads(self, path):
        self.load_state_dict(torch_load(Path(path) / "stage_sampler.pt", "stage sampler state"))

    def __repr__(self) -> str:
        return f"{type(self).__name__}(num_stages={self.num_stages}, counts={self._counts.tolist()})"


class StageRingWriter(Writer):
    """A TorchRL writer giving each trajectory stage ``j`` its own FIFO ring of ``capacity`` slots.

    Stage ``j`` owns storage slots ``[j * capacity, (j + 1) * capacity)``; an item is written to the
    ring of its ``stage_key`` label, overwriting that stage's oldest item once the ring is full.
    """

    def __init__(self, num_stages: int, capacity: int, stage_key: str = TRAJ_STAGE_KEY):
        super().__init__()
        if capacity < 1:
            raise ValueError("capacity per stage must be >= 1")
        self.num_stages, self.capacity, self.stage_key = int(num_stages), int(capacity), stage_key
        self._empty()

    def _empty(self, empty_write_count: bool = True) -> None:
        self._cursor = torch.zeros(self.num_stages + 1, dtype=torch.long)
        self._filled = torch.zeros(self.num_stages + 1, dtype=torch.long)
        if empty_write_count or not hasattr(self, "_write_count"):
            self._write_count = 0

    def add(self, data) -> int:
        return int(self.extend(data.unsqueeze(0))[0])

    def extend(self, data) -> torch.Tensor:
        stages = data.get(self.stage_key).reshape(-1).long().cpu()
        if stages.numel() == 0:
            raise RuntimeError("StageRingWriter.extend got no items")
        if stages.min() < 0 or stages.max() > self.num_stages:
            raise ValueError(f"stage labels must lie in [0, {self.num_stages}]")
        keep, index, cursor, filled = [], [], self._cursor.clone(), self._filled.clone()
        C = self.capacity
        for j in stages.unique().tolist():
            items = (stages == j).nonzero().reshape(-1)[-C:]  # more than a ring holds: the last C win
            n = items.numel()
            index.append(j * C + (cursor[j] + torch.arange(n)) % C)
            keep.append(items)
            cursor[j] = (cursor[j] + n) % C
            filled[j] = min(C, int(filled[j]) + n)
        keep, index = torch.cat(keep), torch.cat(index)
        order = keep.argsort()
        keep, index = keep[order], index[order]
        high = max(len(self._storage), int(index.max()) + 1)
        self._storage.set(index, data[keep] if keep.numel() < stages.numel() else data)
        # bookkeeping only once the data is in: an interrupted write leaves the rings as they were
        self._storage._len = high  # the storage reads slots below its length: rings leave gaps
        self._cursor, self._filled = cursor, filled
        self._write_count += int(stages.numel())
        return index

    def filled(self) -> torch.Tensor:
        """Items held by each stage's ring."""
        return self._filled.clone()

    def slots_by_age(self, stage: int) -> torch.Tensor:
        """Storage slots of ``stage``, oldest first."""
        return torch.cat([torch.arange(a, b) for a, b in self.slot_ranges(stage)] or [torch.zeros(0, dtype=torch.long)])

    def slot_ranges(self, stage: int) -> list[tuple[int, int]]:
        """``stage``'s storage slots as at most two ``[start, stop)`` ranges, oldest first (a wrapped ring: two)."""
        C, n, cursor = self.capacity, int(self._filled[stage]), int(self._cursor[stage])
        start = stage * C
        if n == 0:
            return []
        if n < C or cursor == 0:
            return [(start, start + n)]
        return [(start + cursor, start + C), (start, start + cursor)]

    def state_dict(self) -> dict[str, Any]:
        return {"cursor": self._cursor.clone(), "filled": self._filled.clone(), "write_count": self._write_count}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self._cursor = state_dict["cursor"].clone()
        self._filled = state_dict["filled"].clone()
        self._write_count = int(state_dict["write_count"])

    def dumps(self, path):
        path = Path(path)
        path.mkdir(parents=True, exist_ok=True)
        torch.save(self.state_dict(), path / "stage_ring_writer.pt")

    def loads(self, path):
        self.load_state_dict(torch_load(Path(path) / "stage_ring_writer.pt", "stage writer state"))

    def __repr__(self) -> str:
        return f"{type(self).__name__}(capacity_per_stage={self.capacity}, filled={self._filled.tolist()})"


class StageBuffers(ReplayBuffer):
    """The stage buffers ``B_0..B_N`` of Algorithm 1: one TorchRL replay buffer, one storage.

    Args:
        num_stages: ``N``.
        keys: entries of each ``next`` state to keep (the reward's inputs and the stage index).
        capacity: transitions held by each stage buffer (its oldest overwritten first).
        stage_key: per-state stage index entry.
        batch_size: per-(stage, label) batch size of :meth:`sample_discriminator_batch`.
        scratch_dir: if given, a :class:`~torchrl.data.LazyMemmapStorage` on disk in a new folder inside it
            (removed with the buffers), so very large buffers need not sit in memory.
    """

    def __init__(
        self,
        num_stages: int,
        keys: Sequence[str],
        capacity: int = 1_000_000,
        *,
        stage_key: str = "stage",
        batch_size: int = 256,
        scratch_dir: str | None = None,
    ):
        size = (int(num_stages) + 1) * int(capacity)  # lazily allocated: untouched slots cost no memory
        own_dir = None
        if scratch_dir:  # a folder of its own inside: runs (a sweep, a resume) can share scratch_dir
            Path(scratch_dir).mkdir(parents=True, exist_ok=True)
            own_dir = tempfile.mkdtemp(prefix="stage-buffers-", dir=scratch_dir)
        storage = (
            LazyMemmapStorage(size, scratch_dir=own_dir, auto_cleanup=True) if own_dir else LazyTensorStorage(size)
        )
        super().__init__(
            storage=storage, sampler=StageSampler(num_stages), writer=StageRingWriter(num_stages, capacity)
        )
        if own_dir:
            weakref.finalize(self, shutil.rmtree, own_dir, True)
        self.disc_batch_size = int(batch_size)
        self.num_stages = int(num_stages)
        self.keys = list(dict.fromkeys([*keys, stage_key]))
        self.stage_key = stage_key
        self.episodes_per_stage = np.zeros(self.num_stages + 1, dtype=np.int64)

    @property
    def stage_sampler(self) -> StageSampler:
        return self._sampler

    def __len__(self) -> int:
        return int(self._writer.filled().sum())

    def stage_data(self, stage: int) -> TensorDictBase:
        """The items filed under ``stage``, oldest first."""
        return self._storage._storage[self._writer.slots_by_age(stage)]

    def snapshot_parts(self) -> list[TensorDictBase]:
        """Each stage's items, oldest first (what :func:`~drs_torchrl.data.persistence.dump_buffer` saves): views
        of the storage, so that measuring and saving a snapshot copies nothing in memory."""
        storage = self._storage._storage
        return [storage[a:b] for j in range(self.num_stages + 1) for a, b in self._writer.slot_ranges(j)]

    def add_trajectory(self, trajectory: TensorDictBase, *, demo: bool = False) -> int:
        """File one finished trajectory (a ``(T,)`` TensorDict of transitions with ``"next"``).

        Reads the ``next`` states (the reward is a function of ``s'``); returns the stage it was
        filed under. Demonstrations go to the top stage whatever their labels say.
        """
        states = trajectory.get("next") if "next" in trajectory.keys() else trajectory
        if states.batch_dims != 1:
            raise ValueError(
                f"add_trajectory expects one trajectory with batch shape (T,), got {tuple(states.batch_size)}"
            )
        stages = states.get(self.stage_key).reshape(-1)
        top = self.num_stages if demo else trajectory_stage(stages)
        keep = states.shape[0] if demo else truncate_failed(stages, self.num_stages)
        data = states[:keep].select(*self.keys).clone()
        data.set(TRAJ_STAGE_KEY, torch.full((keep,), top, dtype=torch.long))
        self.extend(data)
        self.episodes_per_stage[top] += 1
        return top

    def stage_counts(self) -> np.ndarray:
        """Transitions currently filed under each stage (``N + 1`` entries)."""
        return self._sampler.stage_counts(self._storage)

    def valid_discriminators(self) -> torch.Tensor:
        return torch.from_numpy(self._sampler.valid_discriminators(self._storage))

    def sample_discriminator_batch(self, batch_size: int | None = None) -> TensorDictBase:
        """A ``(N, 2, B)`` TensorDict: ``[k, 0]`` negatives and ``[k, 1]`` positives of discriminator ``k``.

        Adds ``"label"`` (float, 1 for positives) and ``"valid"`` (whether discriminator ``k`` has data
        on both sides), both broadcast to ``(N, 2, B)``.
        """
        B = batch_size or self.disc_batch_size
        data, info = self.sample(B, return_info=True)
        data = data.reshape(self.num_stages, 2, B)
        label = torch.zeros(self.num_stages, 2, B, 1)
        label[:, 1] = 1.0
        data.set("label", label)
        data.set("valid", info["valid"].view(-1, 1, 1, 1).expand(self.num_stages, 2, B, 1).clone())
        return data

    def dumps(self, path):
        """Write the buffers to ``path`` (TorchRL's on-disk format, memory-mapped storage)."""
        super().dumps(path)
        torch.save(
            {"episodes_per_stage": torch.from_numpy(self.episodes_per_stage.copy())}, Path(path) / "stage_buffers.pt"
        )

    def loads(self, path):
        super().loads(path)
        extra = torch_load(Path(path) / "stage_buffers.pt", "stage buffer state")
        self.episodes_per_stage = extra["episodes_per_stage"].numpy().astype(np.int64)

    def state_dict(self) -> dict[str, Any]:
        sd = super().state_dict()
        sd["episodes_per_stage"] = torch.from_numpy(self.episodes_per_stage.copy())
        return sd

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        state_dict = dict(state_dict)
        eps = state_dict.pop("episodes_per_stage", None)
        super().load_state_dict(state_dict)
        if eps is not None:
            self.episodes_per_stage = np.asarray(eps, dtype=np.int64)


class TrajectoryAssembler:
    """Assemble finished episodes from collector batches, which may each hold part of an episode.

    Collector batches have shape ``(*env_batch, T)``; an episode may span several batches. ``add``
    returns the episodes that ended in this batch, each a ``(T_ep,)`` TensorDict, in order of ending.
    Unfinished parts are kept by the collector's trajectory id (``("collector", "traj_ids")``, unique
    across the workers of a multi-process collector, whose batches arrive interleaved), or by env
    index in the batch when the batch carries no trajectory ids.
    """

    def __init__(self, done_key=("next", "done"), traj_key=("collector", "traj_ids")):
        self.done_key = done_key
        self.traj_key = traj_key
        self._partial: dict[tuple, list[TensorDictBase]] = {}

    def add(self, batch: TensorDictBase) -> list[TensorDictBase]:
        if batch.batch_dims == 1:
            per_env = [batch]
        else:
            per_env = list(batch.reshape(-1, batch.shape[-1]).unbind(0))
        finished = []
        for i, td in enumerate(per_env):
            done = td.get(self.done_key).reshape(-1)
            ids = td.get(self.traj_key, None)
            ids = ids.reshape(-1) if ids is not None else None
            ends = done.nonzero().reshape(-1).tolist()
            start = 0
            for end in ends:
                key = ("traj", int(ids[start])) if ids is not None else ("env", i)
                parts = self._partial.pop(key, []) + [td[start : end + 1]]
                finished.append(torch.cat(parts, 0) if len(parts) > 1 else parts[0].clone())
                start = end + 1
            if start < td.shape[0]:
                key = ("traj", int(ids[start])) if ids is not None else ("env", i)
                self._partial.setdefault(key, []).append(td[start:].clone())
        return finished

    def reset(self):
        self._partial.clear()
