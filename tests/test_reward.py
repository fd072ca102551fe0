"""The DrS reward (Eq. 4): the stage-ordering guarantee, where it applies, and checkpoints."""

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from tensordict import TensorDict
from torchrl.data import Composite, LazyTensorStorage, ReplayBuffer, Unbounded

from drs_torchrl.transforms import DrSReward, RewardCheckpointError
from drs_torchrl.transforms.reward import CHECKPOINT_VERSION, load_reward

OBS = 7


def make_reward(N=3, formula="rescaled", alpha=1 / 3, **kw):
    return DrSReward(N, ["observation"], {"observation": OBS}, formula=formula, alpha=alpha, **kw)


def states(stage, n, scale, gen):
    return TensorDict(
        {"observation": torch.randn(n, OBS, generator=gen) * scale, "stage": torch.full((n, 1), stage)},
        batch_size=[n],
    )


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    N=st.integers(1, 5),
    formula=st.sampled_from(["paper", "rescaled"]),
    alpha=st.floats(0.01, 0.499),
    weight_scale=st.floats(0.1, 100.0),
    obs_scale=st.floats(0.1, 100.0),
)
def test_every_state_of_stage_k_plus_1_beats_every_state_of_stage_k(seed, N, formula, alpha, weight_scale, obs_scale):
    gen = torch.Generator().manual_seed(seed)
    r = make_reward(N, formula, alpha)
    with torch.no_grad():
        for p in r.discriminators.parameters():
            p.copy_(torch.randn(p.shape, generator=gen) * weight_scale)
        r.discriminators.trained.fill_(True)  # untrained ones would contribute 0
    rewards = [r.reward(states(k, 64, obs_scale, gen)).squeeze(-1) for k in range(N + 1)]
    # the dense term is really there: rewards differ from those of zero logits (tanh = 0)
    base = [float(r.combine(torch.zeros(1, N), torch.tensor([[k]]))) for k in range(N)]
    assert any(float((rewards[k] - base[k]).abs().max()) > 0 for k in range(N))
    for k in range(N):
        assert rewards[k + 1].min() > rewards[k].max(), (k, rewards[k].max(), rewards[k + 1].min())


def test_sum_ablation_ignores_stage_and_can_break_ordering():
    r = make_reward(formula="sum")
    x = TensorDict({"observation": torch.zeros(2, OBS), "stage": torch.tensor([[0], [3]])}, [2])
    out = r.reward(x)
    assert out[0] == out[1]


def test_top_stage_has_no_dense_term_and_bounds():
    r = make_reward(N=3, formula="paper")
    x = TensorDict({"observation": torch.randn(5, OBS), "stage": torch.full((5, 1), 3)}, [5])
    assert torch.allclose(r.reward(x), torch.full((5, 1), 3.0))
    rr = make_reward(N=3, formula="rescaled")
    assert torch.allclose(rr.reward(x), torch.full((5, 1), -1.0))  # (3*3 + 0)/(3*3) - 2
    lo, hi = rr.reward_bounds()
    assert hi == pytest.approx(-1.0) and lo == pytest.approx(-2 - 1 / 9, abs=1e-4)


@pytest.mark.parametrize(
    "formula,N,alpha,offset,low,high",
    [
        # paper, Eq. 4: k + alpha*tanh(D_k) over k = 0..N, the top stage N without a dense term: (-alpha, N)
        ("paper", 3, 1 / 3, -2.0, -1 / 3, 3.0),
        ("paper", 2, 0.25, -2.0, -0.25, 2.0),
        # rescaled (the authors' code): (k + alpha*tanh(D_k))/N + offset: (offset - alpha/N, offset + 1)
        ("rescaled", 3, 1 / 3, -2.0, -2 - 1 / 9, -1.0),
        ("rescaled", 2, 0.25, -1.0, -1.125, 0.0),
        # sum of tanh (Appendix F.3), whatever the stage: (-N, N)
        ("sum", 3, 1 / 3, -2.0, -3.0, 3.0),
        ("sum", 1, 1 / 3, -2.0, -1.0, 1.0),
    ],
)
def test_each_formula_declares_its_range_and_saturated_discriminators_reach_it(formula, N, alpha, offset, low, high):
    r = make_reward(N, formula, alpha, offset=offset)
    assert r.reward_bounds() == pytest.approx((low, high), abs=1e-12)
    spec = r.transform_reward_spec(Composite(reward=Unbounded((1,))))["reward"]
    assert (float(spec.space.low), float(spec.space.high)) == pytest.approx((low, high), abs=1e-6)
    assert spec.dtype == torch.float32

    def saturated(logit, stage):
        with torch.no_grad():
            for net in r.discriminators.nets:
                net[-1].weight.zero_()
                net[-1].bias.fill_(logit)
        r.discriminators.trained.fill_(True)
        x = TensorDict({"observation": torch.randn(4, OBS), "stage": torch.full((4, 1), stage)}, [4])
        return r.reward(x)

    lowest = saturated(-5.0, 0)  # tanh(-5) = -0.99991: within 1e-3 of the infimum, never below it
    assert (lowest > low).all() and (lowest < low + 1e-3).all(), lowest
    highest = saturated(5.0, N) if formula == "sum" else saturated(-5.0, N)  # the top stage: no dense term
    if formula == "sum":
        assert (highest < high).all() and (highest > high - 1e-3).all(), highest
    else:
        assert torch.equal(highest, torch.full((4, 1), high))  # success attains the maximum


@pytest.mark.parametrize("alpha", [0.5, 0.7, 0.0, -0.1])
def test_alpha_outside_ordering_range_is_rejected(alpha):
    with pytest.raises(ValueError, match="1/2"):
        make_reward(alpha=alpha)


def test_reward_recomputed_on_replay_buffer_samples_with_current_weights():
    r = make_reward()
    rb = ReplayBuffer(storage=LazyTensorStorage(100), batch_size=16, transform=r)
    n = 50
    data = TensorDict(
        {
            "observation": torch.randn(n, OBS),
            "next": {
                "observation": torch.randn(n, OBS),
                "stage": torch.randint(0, 4, (n, 1)),
                "reward": torch.zeros(n, 1),
            },
        },
        batch_size=[n],
    )
    rb.extend(data)
    r.discriminators.trained.fill_(True)
    s1 = rb.sample()
    assert torch.allclose(s1["next", "reward"], r.reward(s1["next"]))
    with torch.no_grad():
        for p in r.discriminators.parameters():
            p.add_(1.0)
    s2 = rb.sample()
    assert torch.allclose(s2["next", "reward"], r.reward(s2["next"]))
    assert torch.count_nonzero(rb.storage[:n]["next", "reward"]) == 0  # storage untouched


def test_checkpoint_round_trip(tmp_path):
    r = make_reward(metadata={"family": "pick_cube"}, hidden=[16, 8], activation="relu")
    with torch.no_grad():
        for p in r.discriminators.parameters():
            p.normal_()
        r.discriminators.trained[:2] = True
    path = r.save(tmp_path / "reward.pt", frames=123)
    loaded = DrSReward.from_checkpoint(path)
    x = TensorDict({"observation": torch.randn(20, OBS), "stage": torch.randint(0, 4, (20, 1))}, [20])
    assert torch.allclose(loaded.reward(x), r.reward(x))
    assert loaded.metadata == {"family": "pick_cube", "frames": 123}
    assert loaded.formula == r.formula and loaded.alpha == r.alpha and loaded.discriminators.hidden == [16, 8]
    assert not list(tmp_path.glob("*.tmp"))
    assert loaded.discriminators.trained.tolist() == [True, True, False]


def spec(**dims):
    return Composite({k: Unbounded(shape=(d,)) for k, d in dims.items()})


def test_check_compatible_names_every_difference():
    r = make_reward(metadata={"family": "pick_cube"})
    r.check_compatible(spec(observation=OBS, stage=1), num_stages=3, family="pick_cube")
    with pytest.raises(RewardCheckpointError) as e:
        r.check_compatible(spec(observation=OBS + 2), num_stages=2, family="stack_cube")
    msg = str(e.value)
    assert "family 'pick_cube'" in msg and "'stack_cube'" in msg
    assert "3 stages" in msg and "has 2" in msg
    assert f"size {OBS}" in msg and f"size {OBS + 2}" in msg
    assert "stage index" in msg
    with pytest.raises(RewardCheckpointError, match="does not produce"):
        r.check_compatible(spec(state=OBS, stage=1))


def test_check_compatible_refuses_other_stages_of_the_same_count():
    """A reward learned on [is_obj_placed, is_grasped, success] scores "beyond placed" with D_0: an env
    staged by other indicators (a stage ablation) has as many stages but other meanings."""
    keys = ["is_obj_placed", "is_grasped", "success"]
    r = make_reward(metadata={"family": "pick_cube", "stage_keys": keys})
    env = spec(observation=OBS, stage=1)
    r.check_compatible(env, num_stages=3, family="pick_cube", stage_keys=keys)
    with pytest.raises(RewardCheckpointError) as e:
        r.check_compatible(env, num_stages=3, family="pick_cube", stage_keys=["is_grasped", "is_obj_placed", "success"])
    assert "env.stages=[is_obj_placed,is_grasped,success]" in str(e.value)
    make_reward(metadata={"family": "pick_cube"}).check_compatible(env, num_stages=3, stage_keys=["a", "b", "c"])


def test_bad_checkpoint_files_get_clear_errors(tmp_path):
    with pytest.raises(RewardCheckpointError, match="does not exist"):
        DrSReward.from_checkpoint(tmp_path / "nope.pt")
    good = make_reward().save(tmp_path / "r.pt")
    data = good.read_bytes()
    (tmp_path / "trunc.pt").write_bytes(data[: len(data) // 2])
    with pytest.raises(RewardCheckpointError, match="corrupt or truncated"):
        DrSReward.from_checkpoint(tmp_path / "trunc.pt")
    torch.save({"actor": {}}, tmp_path / "policy.pt")
    with pytest.raises(RewardCheckpointError, match="not a drs-torchrl reward checkpoint"):
        DrSReward.from_checkpoint(tmp_path / "policy.pt")
    payload = torch.load(good, weights_only=True)
    payload["version"] = CHECKPOINT_VERSION + 1
    torch.save(payload, tmp_path / "future.pt")
    with pytest.raises(RewardCheckpointError, match="newer"):
        DrSReward.from_checkpoint(tmp_path / "future.pt")
    payload = torch.load(good, weights_only=True)
    del payload["config"]["formula"]
    torch.save(payload, tmp_path / "no_formula.pt")
    with pytest.raises(RewardCheckpointError, match=r"damaged: its settings lack \['formula'\]"):
        DrSReward.from_checkpoint(tmp_path / "no_formula.pt")
    del payload["state_dict"]
    torch.save(payload, tmp_path / "no_weights.pt")
    with pytest.raises(RewardCheckpointError, match="damaged: it lacks its state_dict"):
        load_reward(tmp_path / "no_weights.pt")


def test_nan_weights_are_refused(tmp_path):
    r = make_reward()
    with torch.no_grad():
        r.discriminators.nets[1][0].weight[0, 0] = float("nan")
    r.save(tmp_path / "nan.pt")
    with pytest.raises(RewardCheckpointError, match="non-finite"):
        DrSReward.from_checkpoint(tmp_path / "nan.pt")


@pytest.mark.parametrize("formula", ["paper", "rescaled"])
@pytest.mark.parametrize(
    "stage, shown",
    [
        ([-1, 0], "got -1"),
        ([3, 7, 99], "got 7, 99"),
        ([0.9, 2.0], "got 0.9"),
        ([2.99], "got 2.99"),
        ([float("nan")], "got nan"),
    ],
)
def test_stages_outside_0_to_N_or_not_whole_are_refused_not_clamped(formula, stage, shown):
    r = make_reward(N=3, formula=formula)
    r.discriminators.trained.fill_(True)
    n = len(stage)
    x = TensorDict({"observation": torch.zeros(n, OBS), "stage": torch.tensor(stage).reshape(n, 1)}, [n])
    with pytest.raises(ValueError, match=r"stage labels \('stage'\) must lie in \[0, 3\]") as e:
        r.reward(x)
    assert str(e.value).endswith(shown)
    ok = TensorDict({"observation": torch.zeros(4, OBS), "stage": torch.tensor([[0.0], [1.0], [2.0], [3.0]])}, [4])
    assert r.reward(ok).shape == (4, 1)  # whole-numbered floats in [0, N] are fine


def test_an_input_of_the_wrong_size_is_named():
    r = make_reward(N=3)
    x = TensorDict({"observation": torch.zeros(2, OBS + 1), "stage": torch.zeros(2, 1, dtype=torch.long)}, [2])
    with pytest.raises(ValueError, match=rf"reads 'observation' of size {OBS} .*'observation' has size {OBS + 1}"):
        r.reward(x)
