"""The per-stage discriminator loss: learns separable data, early stop freezes a stage."""

import torch
from tensordict import TensorDict

from drs_torchrl.data import StageBuffers
from drs_torchrl.objectives import DiscriminatorLoss
from drs_torchrl.transforms import DrSReward

N, OBS = 2, 3


def separable_buffers():
    """Stage-j trajectories have observations centred on +-2 along axis j (separable per stage)."""
    gen = torch.Generator().manual_seed(0)
    sb = StageBuffers(N, ["observation"], capacity=10_000, batch_size=128)
    for j in range(N + 1):
        for _ in range(20):
            T = 10
            obs = torch.randn(T, OBS, generator=gen) * 0.3
            obs[:, :N] += torch.tensor([2.0 if j > k else -2.0 for k in range(N)])
            nxt = TensorDict({"observation": obs, "stage": torch.full((T, 1), j)}, [T])
            sb.add_trajectory(TensorDict({"next": nxt}, [T]))
    return sb


def test_learns_separable_data_to_full_accuracy():
    torch.manual_seed(0)
    sb = separable_buffers()
    reward = DrSReward(N, ["observation"], {"observation": OBS})
    loss = DiscriminatorLoss(reward.discriminators, ["observation"], early_stop_threshold=None)
    opt = torch.optim.Adam(reward.discriminators.parameters(), lr=1e-2)
    first = loss(sb.sample_discriminator_batch())
    for _ in range(300):
        out = loss(sb.sample_discriminator_batch())
        opt.zero_grad()
        out["loss_discriminator"].backward()
        opt.step()
    out = loss(sb.sample_discriminator_batch())
    for k in range(N):
        assert out[f"accuracy_{k}"] > 0.99
        assert out[f"loss_{k}"] < first[f"loss_{k}"] * 0.5
    # the learned reward ranks positives of stage k above its negatives within the same stage
    x0 = TensorDict(
        {"observation": torch.tensor([[2.0, -2.0, 0.0], [-2.0, -2.0, 0.0]]), "stage": torch.tensor([[0], [0]])}, [2]
    )
    r = reward.reward(x0)
    assert r[0] > r[1]


def test_early_stop_freezes_a_stage_that_is_passed_often():
    torch.manual_seed(0)
    sb = separable_buffers()
    reward = DrSReward(N, ["observation"], {"observation": OBS})
    loss = DiscriminatorLoss(reward.discriminators, ["observation"], early_stop_threshold=0.95, window=20, latch=False)
    loss.record_episodes([1] * 20)  # every recent episode got beyond stage 0, none beyond stage 1
    assert loss.beyond_rates().tolist() == [1.0, 0.0]
    assert loss.training_mask().tolist() == [False, True]
    before = [p.clone() for p in reward.discriminators.nets[0].parameters()]
    opt = torch.optim.Adam(reward.discriminators.parameters(), lr=1e-2)
    for _ in range(5):
        out = loss(sb.sample_discriminator_batch())
        opt.zero_grad(set_to_none=True)
        out["loss_discriminator"].backward()
        opt.step()
    assert out["active_0"] == 0 and out["active_1"] == 1
    for a, b in zip(before, reward.discriminators.nets[0].parameters()):
        assert torch.equal(a, b)
    loss.record_episodes([0] * 20)  # rolling window: stage 0 is hard again, training resumes
    assert loss.training_mask().tolist() == [True, True]


def test_latched_early_stop_is_permanent_and_untrained_stages_add_nothing():
    reward = DrSReward(N, ["observation"], {"observation": OBS}, formula="paper")
    x = TensorDict({"observation": torch.randn(8, OBS), "stage": torch.tensor([[0], [1]] * 4)}, [8])
    assert torch.equal(reward.reward(x), x["stage"].float())  # nothing trained yet: plain stage index
    loss = DiscriminatorLoss(reward.discriminators, ["observation"], early_stop_threshold=0.95, window=10)
    loss.record_episodes([1] * 10)
    assert loss.training_mask().tolist() == [False, True]
    loss.record_episodes([0] * 10)
    assert loss.training_mask().tolist() == [False, True]  # latched
    sb = separable_buffers()
    loss(sb.sample_discriminator_batch())
    assert reward.discriminators.trained.tolist() == [False, True]
    r = reward.reward(x)
    assert torch.equal(r[x["stage"].squeeze(-1) == 0], torch.zeros(4, 1))
    assert not torch.equal(r[x["stage"].squeeze(-1) == 1], torch.ones(4, 1))
