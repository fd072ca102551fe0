"""Compact replay-buffer snapshots: same transitions, same age order, oldest overwritten first."""
import torch
from tensordict import TensorDict
from torchrl.data import LazyTensorStorage, ReplayBuffer

from drs_torchrl.data import StageBuffers
from drs_torchrl.data.persistence import dump_buffer, load_buffer


def items(a, b):
    return TensorDict({"x": torch.arange(a, b, dtype=torch.float32)[:, None]}, [b - a])


def test_wrapped_buffer_round_trip_keeps_age_order(tmp_path):
    rb = ReplayBuffer(storage=LazyTensorStorage(10))
    rb.extend(items(0, 14))  # slots hold 10..13, 4..9; the oldest is 4
    meta = dump_buffer(rb, tmp_path / "rb")
    assert meta["len"] == 10
    rb2 = ReplayBuffer(storage=LazyTensorStorage(10))
    load_buffer(rb2, tmp_path / "rb")
    assert sorted(rb2[:10]["x"].squeeze(-1).tolist()) == list(range(4, 14))
    rb2.extend(items(100, 102))  # must replace the two oldest (4 and 5)
    assert sorted(rb2[:10]["x"].squeeze(-1).tolist()) == [*range(6, 14), 100, 101]


def test_snapshot_size_follows_content_not_capacity(tmp_path):
    rb = ReplayBuffer(storage=LazyTensorStorage(1_000_000))
    rb.extend(items(0, 100))
    dump_buffer(rb, tmp_path / "rb")
    size = sum(f.stat().st_size for f in (tmp_path / "rb").rglob("*") if f.is_file())
    assert size < 100_000


def test_stage_buffers_round_trip(tmp_path):
    sb = StageBuffers(2, ["observation"], capacity=100, batch_size=4)
    for stages in ([0, 0, 1, 0], [0, 2, 2], [0, 0]):
        T = len(stages)
        sb.add_trajectory(TensorDict({"next": {"observation": torch.randn(T, 3), "stage": torch.tensor(stages)[:, None]}}, [T]))
    dump_buffer(sb, tmp_path / "sb")
    sb2 = StageBuffers(2, ["observation"], capacity=100, batch_size=4)
    load_buffer(sb2, tmp_path / "sb")
    assert sb2.stage_counts().tolist() == sb.stage_counts().tolist() == [2, 3, 3]
    assert torch.equal(sb2[: len(sb2)]["observation"], sb[: len(sb)]["observation"])
    assert sb2.sample_discriminator_batch().shape == (2, 2, 4)


def _traj(stages, start):
    T = len(stages)
    return TensorDict({"next": {"observation": torch.arange(start, start + T, dtype=torch.float32)[:, None],
                                "stage": torch.tensor(stages)[:, None]}}, [T])


def test_full_wrapped_stage_buffers_round_trip(tmp_path):
    sb = StageBuffers(2, ["observation"], capacity=10, batch_size=4)
    sb.add_trajectory(_traj([2] * 6, 0))
    sb.add_trajectory(_traj([0] * 4, 100))
    sb.add_trajectory(_traj([1] * 3, 200))  # wraps: overwrites three stage-2 slots
    assert sb.stage_counts().tolist() == [4, 3, 3]
    dump_buffer(sb, tmp_path / "sb")
    assert (tmp_path / "sb" / "part1").is_dir()  # oldest-first in two parts
    sb2 = StageBuffers(2, ["observation"], capacity=10, batch_size=4)
    load_buffer(sb2, tmp_path / "sb")
    assert sb2.stage_counts().tolist() == [4, 3, 3]
    assert sorted(sb2[:10]["observation"].squeeze(-1).tolist()) == sorted(sb[:10]["observation"].squeeze(-1).tolist())
    sb2.add_trajectory(_traj([0, 0], 300))  # the two oldest left are stage-2 slots 3 and 4
    assert sb2.stage_counts().tolist() == [6, 3, 1]


def test_slot_overwritten_twice_before_a_sample_keeps_its_last_label():
    sb = StageBuffers(2, ["observation"], capacity=4, batch_size=2)
    sb.add_trajectory(_traj([2] * 4, 0))
    sb.add_trajectory(_traj([1] * 4, 10))  # overwrites every slot before any sync
    sb.add_trajectory(_traj([0] * 2, 20))  # and two of them again
    assert sb.stage_counts().tolist() == [2, 2, 0]
    assert sb.valid_discriminators().tolist() == [True, False]
