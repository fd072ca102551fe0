"""Compact replay-buffer snapshots: same transitions, same age order, oldest overwritten first."""

import torch
from tensordict import TensorDict
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.envs.transforms import MultiStepTransform

from drs_torchrl.data import TRAJ_STAGE_KEY, StageBuffers
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


def _time_major(rb) -> torch.Tensor:
    """A 2-D storage's filled rows, oldest first: ``(T, envs)``."""
    data, cursor = rb.storage._storage["x"], rb._writer._cursor % rb.storage._storage.shape[0]
    rows = len(rb) // data.shape[1]
    return data[:rows] if rows < data.shape[0] else torch.cat([data[cursor:], data[:cursor]])


def test_a_buffer_with_a_time_dimension_round_trips_wrapped_and_past_its_inverse_transform(tmp_path):
    """The maze's n-step buffer: ``LazyTensorStorage(ndim=2)`` holds ``(T, envs)`` and is extended with ``(envs, T)``;
    its transform (``MultiStepTransform``) made the stored windows, so restoring must not run it again."""

    def make():
        return ReplayBuffer(storage=LazyTensorStorage(60, ndim=2), transform=MultiStepTransform(3, 0.9))

    for batches in (2, 7):  # 16 of 20 rows; wrapped twice with the cursor mid-ring
        rb = make()
        for b in range(batches):
            x = (100.0 * b + torch.arange(3 * 8, dtype=torch.float32)).reshape(3, 8)
            done = torch.zeros(3, 8, 1, dtype=torch.bool)
            rb.extend(
                TensorDict(
                    {
                        "x": x,
                        "next": {"x": x + 1, "reward": torch.ones(3, 8, 1), "done": done, "terminated": done},
                    },
                    [3, 8],
                )
            )
        dump_buffer(rb, tmp_path / f"rb{batches}")
        rb2 = make()
        load_buffer(rb2, tmp_path / f"rb{batches}")
        assert len(rb2) == len(rb) and torch.equal(_time_major(rb2), _time_major(rb))
        assert torch.equal(rb2.storage._storage["steps_to_next_obs"][: len(rb) // 3].unique(), torch.tensor([3]))
        assert rb2._transform[0]._buffer is None  # the restore went past the n-step transform


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
        sb.add_trajectory(
            TensorDict({"next": {"observation": torch.randn(T, 3), "stage": torch.tensor(stages)[:, None]}}, [T])
        )
    dump_buffer(sb, tmp_path / "sb")
    sb2 = StageBuffers(2, ["observation"], capacity=100, batch_size=4)
    load_buffer(sb2, tmp_path / "sb")
    assert sb2.stage_counts().tolist() == sb.stage_counts().tolist() == [2, 3, 3]
    for j in range(3):
        assert torch.equal(sb2.stage_data(j)["observation"], sb.stage_data(j)["observation"])
    assert sb2.sample_discriminator_batch().shape == (2, 2, 4)


def _traj(stages, start):
    T = len(stages)
    return TensorDict(
        {
            "next": {
                "observation": torch.arange(start, start + T, dtype=torch.float32)[:, None],
                "stage": torch.tensor(stages)[:, None],
            }
        },
        [T],
    )


def test_full_wrapped_stage_buffers_round_trip(tmp_path):
    sb = StageBuffers(2, ["observation"], capacity=4, batch_size=4)
    sb.add_trajectory(_traj([2] * 3, 0))
    sb.add_trajectory(_traj([0] * 4, 100))
    sb.add_trajectory(_traj([0] * 3, 200))  # stage 0 wraps: 103 and 200-202 remain
    assert sb.stage_counts().tolist() == [4, 0, 3]
    # the snapshot reads the storage in place (a checkpoint measures and writes it without copying it in memory)
    parts = sb.snapshot_parts()
    store = sb.storage._storage["observation"]
    assert [p["observation"].squeeze(-1).tolist() for p in parts] == [[103.0], [200.0, 201.0, 202.0], [0, 1, 2]]
    assert all(p["observation"].untyped_storage().data_ptr() == store.untyped_storage().data_ptr() for p in parts)
    dump_buffer(sb, tmp_path / "sb")
    sb2 = StageBuffers(2, ["observation"], capacity=4, batch_size=4)
    load_buffer(sb2, tmp_path / "sb")
    assert sb2.stage_counts().tolist() == [4, 0, 3]
    age = sb2.stage_data(0)["observation"].squeeze(-1).tolist()
    assert age == [103.0, 200.0, 201.0, 202.0]
    sb2.add_trajectory(_traj([0], 300))  # evicts the oldest stage-0 state (103), nothing else
    assert sb2.stage_data(0)["observation"].squeeze(-1).tolist() == [200.0, 201.0, 202.0, 300.0]
    assert sb2.stage_counts().tolist() == [4, 0, 3]


def test_ring_overwritten_twice_before_a_sample_keeps_its_last_labels():
    sb = StageBuffers(2, ["observation"], capacity=4, batch_size=2)
    sb.add_trajectory(_traj([1] * 4, 0))
    sb.add_trajectory(_traj([1] * 4, 10))  # overwrites the whole stage-1 ring before any sync
    sb.add_trajectory(_traj([1] * 2, 20))  # and two slots again
    sb.add_trajectory(_traj([0] * 2, 30))
    assert sb.stage_counts().tolist() == [2, 4, 0]
    assert sb.valid_discriminators().tolist() == [True, False]
    b = sb.sample_discriminator_batch()
    assert set(b[TRAJ_STAGE_KEY][0, 1].tolist()) == {1}
