"""Stage monotonicity and indexing (Eq. 2-3) and the StageIndicator transform."""

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Composite, Unbounded

from drs_torchrl.transforms import SemiSparseReward, StageIndicator, monotone_indicators, stage_index

KEYS = ["is_grasped", "is_obj_placed", "success"]


def _td(rows):
    t = torch.tensor(rows, dtype=torch.bool)
    return TensorDict({k: t[:, i : i + 1] for i, k in enumerate(KEYS)}, batch_size=[len(rows)])


def test_monotone_indicators_propagate_later_stages_backwards():
    ind = torch.tensor([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1]], dtype=torch.bool)
    expected = torch.tensor([[0, 0, 0], [1, 0, 0], [1, 1, 0], [1, 1, 1], [1, 1, 1], [1, 1, 1]], dtype=torch.bool)
    assert torch.equal(monotone_indicators(ind), expected)
    assert stage_index(ind).tolist() == [0, 1, 2, 3, 3, 3]


def test_stage_is_highest_true_indicator_plus_one_for_all_combinations():
    for bits in range(8):
        ind = torch.tensor([(bits >> i) & 1 for i in range(3)], dtype=torch.bool)
        highest = max([i + 1 for i in range(3) if ind[i]] or [0])
        assert int(stage_index(ind)) == highest


def test_transform_labels_bare_tensordict_and_next_of_transitions():
    t = StageIndicator(KEYS)
    td = t(_td([[0, 0, 0], [1, 1, 0], [0, 0, 1]]))
    assert td["stage"].squeeze(-1).tolist() == [0, 2, 3]
    assert td["stage"].dtype == torch.int64 and td["stage"].shape == (3, 1)
    assert td["stage_indicators"].tolist() == [[0, 0, 0], [1, 1, 0], [1, 1, 1]]
    transitions = TensorDict({"next": _td([[1, 0, 0], [0, 1, 0]])}, batch_size=[2])
    t(transitions)
    assert transitions["next", "stage"].squeeze(-1).tolist() == [1, 2]
    assert "stage" not in transitions.keys()


def test_semi_sparse_reward_is_stage_plus_offset():
    td = SemiSparseReward(3, offset=-3)(StageIndicator(KEYS)(_td([[0, 0, 0], [1, 0, 0], [1, 1, 1]])))
    assert td["reward"].squeeze(-1).tolist() == [-3.0, -2.0, 0.0]
    td = SemiSparseReward(3)(StageIndicator(KEYS)(_td([[0, 1, 0]])))
    assert td["reward"].item() == 2.0


def test_no_reward_is_written_on_reset():
    labelled = StageIndicator(KEYS)._reset(TensorDict(), _td([[1, 0, 0]]))
    out = SemiSparseReward(3)._reset(TensorDict(), labelled)
    assert "reward" not in out.keys() and out["stage"].item() == 1


def test_stage_labelling_writes_no_reward():
    assert "reward" not in StageIndicator(KEYS)(_td([[1, 1, 1]])).keys()


def test_a_missing_indicator_or_stage_is_named():
    with pytest.raises(KeyError, match="is_obj_placed"):
        StageIndicator(KEYS)(TensorDict({"is_grasped": torch.ones(2, 1, dtype=torch.bool)}, [2]))
    with pytest.raises(KeyError, match="stage"):
        SemiSparseReward(3)(TensorDict({}, [2]))


def test_semi_sparse_reward_spec_is_bounded_and_keeps_a_custom_key():
    spec = Composite(reward=Unbounded(shape=(1,)), shape=())
    out = SemiSparseReward(3, offset=-3).transform_reward_spec(spec.clone())
    assert out["reward"].space.low.item() == -3 and out["reward"].space.high.item() == 0
    custom = SemiSparseReward(3, reward_key="semi").transform_reward_spec(spec.clone())
    assert "semi" in custom.keys() and custom["semi"].dtype == torch.float32
    td = SemiSparseReward(3, reward_key="semi")(StageIndicator(KEYS)(_td([[1, 0, 0]])))
    assert td["semi"].item() == 1.0 and "reward" not in td.keys()
