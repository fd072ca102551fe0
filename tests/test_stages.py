"""Stage monotonicity and indexing (Eq. 2-3) and the StageIndicator transform."""
import torch
from tensordict import TensorDict

from drs_torchrl.transforms import StageIndicator, monotone_indicators, stage_index

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
    td = StageIndicator(KEYS, semi_sparse_reward=True, semi_sparse_offset=-3)(_td([[0, 0, 0], [1, 0, 0], [1, 1, 1]]))
    assert td["reward"].squeeze(-1).tolist() == [-3.0, -2.0, 0.0]
    td = StageIndicator(KEYS, semi_sparse_reward=True)(_td([[0, 1, 0]]))
    assert td["reward"].item() == 2.0


def test_no_reward_is_written_on_reset():
    t = StageIndicator(KEYS, semi_sparse_reward=True)
    out = t._reset(TensorDict(), _td([[1, 0, 0]]))
    assert "reward" not in out.keys() and out["stage"].item() == 1
