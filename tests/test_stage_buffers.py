"""Trajectory filing and truncation, the StageSampler's split and proportions, assembly."""

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from drs_torchrl.data import TRAJ_STAGE_KEY, StageBuffers, TrajectoryAssembler, truncate_failed

N = 3
OBS = 4


def traj(stages, offset=0.0):
    T = len(stages)
    nxt = TensorDict(
        {
            "observation": torch.arange(T, dtype=torch.float32)[:, None].expand(T, OBS) + offset,
            "stage": torch.tensor(stages)[:, None],
            "done": torch.zeros(T, 1, dtype=torch.bool),
        },
        batch_size=[T],
    )
    nxt["done"][-1] = True
    return TensorDict({"observation": torch.zeros(T, OBS), "next": nxt}, batch_size=[T])


def test_truncation_rule():
    assert truncate_failed(torch.tensor([0, 1, 1, 0, 0]), N) == 3
    assert truncate_failed(torch.tensor([0, 2, 1, 2, 1, 0]), N) == 4
    assert truncate_failed(torch.tensor([0, 0, 0]), N) == 3
    assert truncate_failed(torch.tensor([0, 1, 3, 2]), N) == 4  # success: whole


def test_filing_by_highest_stage_with_truncation():
    sb = StageBuffers(N, ["observation"], capacity=1000)
    assert sb.add_trajectory(traj([0, 1, 1, 0, 0])) == 1
    assert sb.add_trajectory(traj([0, 0, 0, 0])) == 0
    assert sb.add_trajectory(traj([0, 1, 2, 3])) == 3
    assert sb.add_trajectory(traj([0, 0, 1, 0]), demo=True) == 3  # demos: top, whole
    assert sb.stage_counts().tolist() == [4, 3, 0, 8]
    assert sb.episodes_per_stage.tolist() == [1, 1, 0, 2]
    # the stage-1 failure kept steps 0..2 (last step at stage 1 is index 2)
    s1 = sb.stage_data(1)
    assert s1["observation"][:, 0].tolist() == [0.0, 1.0, 2.0] and (s1[TRAJ_STAGE_KEY] == 1).all()
    assert sb.stage_data(3)["observation"][:, 0].tolist() == [0.0, 1.0, 2.0, 3.0, 0.0, 1.0, 2.0, 3.0]


def test_buffers_on_disk_can_share_a_scratch_dir_and_clean_up(tmp_path):
    """reward.stage_buffer_scratch_dir: two runs (a sweep, or a resume beside the interrupted process) use one
    folder; each writes its own memory maps there and removes them when it is gone."""
    first, second = (StageBuffers(N, ["observation"], capacity=100, scratch_dir=str(tmp_path)) for _ in range(2))
    for sb in (first, second):
        assert sb.add_trajectory(traj([0, 1, 2, 3])) == 3
    assert second.stage_data(3)["observation"][:, 0].tolist() == [0.0, 1.0, 2.0, 3.0]
    assert len(list(tmp_path.iterdir())) == 2 and list(tmp_path.rglob("*.memmap"))
    del first, second, sb
    import gc

    gc.collect()
    assert list(tmp_path.iterdir()) == []


def test_positives_and_negatives_respect_stage_split():
    sb = StageBuffers(N, ["observation"], capacity=10_000, batch_size=64)
    for stages in ([0] * 5, [0, 1, 1], [1, 2, 2, 2], [1, 2, 3]):
        for _ in range(3):
            sb.add_trajectory(traj(stages))
    batch = sb.sample_discriminator_batch()
    assert batch.shape == (N, 2, 64)
    ts = batch[TRAJ_STAGE_KEY]
    for k in range(N):
        assert (ts[k, 0] <= k).all() and (ts[k, 1] > k).all()
    assert (batch["label"][:, 0] == 0).all() and (batch["label"][:, 1] == 1).all()
    assert batch["valid"].all()


def test_sampling_is_proportional_to_stage_sizes():
    sb = StageBuffers(N, ["observation"], capacity=100_000, batch_size=20_000)
    sizes = {0: 1000, 1: 3000, 2: 500, 3: 1500}
    for s, n in sizes.items():
        stages = [s] * n
        sb.add_trajectory(traj(stages))
    batch = sb.sample_discriminator_batch()
    ts = batch[TRAJ_STAGE_KEY]
    for k in range(N):
        neg = ts[k, 0].reshape(-1).numpy()
        pos = ts[k, 1].reshape(-1).numpy()
        neg_total = sum(sizes[j] for j in range(k + 1))
        pos_total = sum(sizes[j] for j in range(k + 1, N + 1))
        for j in range(k + 1):
            assert np.mean(neg == j) == pytest.approx(sizes[j] / neg_total, abs=0.02)
        for j in range(k + 1, N + 1):
            assert np.mean(pos == j) == pytest.approx(sizes[j] / pos_total, abs=0.02)


def test_discriminator_without_positives_is_marked_invalid():
    sb = StageBuffers(N, ["observation"], capacity=100, batch_size=8)
    sb.add_trajectory(traj([0, 0, 0]))
    sb.add_trajectory(traj([0, 1, 0]))
    assert sb.valid_discriminators().tolist() == [True, False, False]
    assert sb.sample_discriminator_batch()["valid"][:, 0, 0, 0].tolist() == [True, False, False]


def test_each_stage_is_its_own_fifo_ring():
    sb = StageBuffers(N, ["observation"], capacity=4, batch_size=4)
    sb.add_trajectory(traj([3] * 3))
    sb.add_trajectory(traj([0] * 4, offset=10))
    assert sb.stage_counts().tolist() == [4, 0, 0, 3]
    sb.add_trajectory(traj([0] * 2, offset=20))  # stage 0 is full: its two oldest go, stage 3 is untouched
    assert sb.stage_counts().tolist() == [4, 0, 0, 3] and len(sb) == 7
    assert sb.stage_data(0)["observation"][:, 0].tolist() == [12.0, 13.0, 20.0, 21.0]  # oldest first
    batch = sb.sample_discriminator_batch()
    assert (batch[TRAJ_STAGE_KEY][2, 1] == 3).all() and (batch[TRAJ_STAGE_KEY][0, 0] == 0).all()


def test_trajectory_longer_than_its_ring_keeps_its_last_states():
    sb = StageBuffers(N, ["observation"], capacity=3, batch_size=2)
    sb.add_trajectory(traj([0] * 5))
    assert sb.stage_counts().tolist() == [3, 0, 0, 0]
    assert sb.stage_data(0)["observation"][:, 0].tolist() == [2.0, 3.0, 4.0]


def test_state_dict_round_trip():
    sb = StageBuffers(N, ["observation"], capacity=4, batch_size=8)
    sb.add_trajectory(traj([0, 1, 1]))
    sb.add_trajectory(traj([0, 2, 3]))
    sb.add_trajectory(traj([0, 0, 0], offset=10))  # stage 0's ring wraps (4 slots, 6 states)
    sb2 = StageBuffers(N, ["observation"], capacity=4, batch_size=8)
    sb2.load_state_dict(sb.state_dict())
    sb.add_trajectory(traj([0], offset=20))
    sb2.add_trajectory(traj([0], offset=20))  # the restored cursor overwrites the same oldest slot
    assert torch.equal(sb2.stage_data(0)["observation"], sb.stage_data(0)["observation"])
    assert sb2.stage_counts().tolist() == sb.stage_counts().tolist()
    assert sb2.episodes_per_stage.tolist() == [2, 1, 0, 1]
    for j in range(N + 1):
        assert torch.equal(sb2.stage_data(j)["observation"], sb.stage_data(j)["observation"])


def test_assembler_joins_episodes_across_batches_per_env():
    asm = TrajectoryAssembler()

    def batch(done_rows):
        d = torch.tensor(done_rows, dtype=torch.bool)[..., None]
        step = torch.arange(d.shape[-2], dtype=torch.float32).expand(d.shape[:-1])[..., None]
        return TensorDict({"t": step, "next": {"done": d}}, batch_size=d.shape[:-1])

    assert asm.add(batch([0, 0, 0])) == []
    eps = asm.add(batch([0, 1, 0]))
    assert [e.shape[0] for e in eps] == [5]
    eps = asm.add(batch([1, 0, 1]))
    assert [e.shape[0] for e in eps] == [2, 2]
    # two envs, batch shape (2, T)
    eps = asm.add(batch([[0, 1, 0, 0], [1, 0, 0, 1]]))
    assert [e.shape[0] for e in eps] == [2, 1, 3]


def test_assembler_keeps_interleaved_workers_apart_by_trajectory_id():
    """Batches of a two-worker collector arrive interleaved; episodes are joined by trajectory id."""
    asm = TrajectoryAssembler()

    def batch(worker, ids, done, t0):
        n = len(ids)
        return TensorDict(
            {
                "worker": torch.full((n, 1), worker),
                "t": torch.arange(t0, t0 + n)[:, None],
                "collector": {"traj_ids": torch.tensor(ids)},
                "next": {"done": torch.tensor(done, dtype=torch.bool)[:, None]},
            },
            batch_size=[n],
        )

    assert asm.add(batch(0, [0, 0, 0], [0, 0, 0], 0)) == []
    assert asm.add(batch(1, [1, 1, 1], [0, 0, 0], 0)) == []
    (a,) = asm.add(batch(0, [0, 2, 2], [1, 0, 0], 3))  # worker 0's episode 0 ends
    assert a["worker"].unique().tolist() == [0] and a["t"].reshape(-1).tolist() == [0, 1, 2, 3]
    (b,) = asm.add(batch(1, [1, 1, 3], [0, 1, 0], 3))
    assert b["worker"].unique().tolist() == [1] and b["t"].reshape(-1).tolist() == [0, 1, 2, 3, 4]
    (c,) = asm.add(batch(0, [2], [1], 6))
    assert c["t"].reshape(-1).tolist() == [4, 5, 6] and c["worker"].unique().tolist() == [0]


def test_mixed_stages_in_one_extend_and_placeholders_point_at_filed_data():
    sb = StageBuffers(N, ["observation"], capacity=10, batch_size=4)
    data = TensorDict(
        {
            "observation": torch.arange(6.0)[:, None].expand(6, OBS),
            "stage": torch.zeros(6, 1, dtype=torch.long),
            TRAJ_STAGE_KEY: torch.tensor([3, 0, 0, 3, 1, 0]),
        },
        [6],
    )
    sb.extend(data)
    assert sb.stage_counts().tolist() == [3, 1, 0, 2]
    assert sb.stage_data(3)["observation"][:, 0].tolist() == [0.0, 3.0]
    only_top = StageBuffers(N, ["observation"], capacity=10, batch_size=4)
    only_top.add_trajectory(traj([0, 3]), demo=True)
    b = only_top.sample_discriminator_batch()  # no negatives anywhere: placeholders, marked invalid
    assert not b["valid"].any() and (b[TRAJ_STAGE_KEY] == 3).all()
