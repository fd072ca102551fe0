"""Every reward transform of the slot through TorchRL's standard transform checks: one env, inside and
outside a batched env (serial and parallel), composed, on a replay buffer, on a bare TensorDict and in
a model (the cases of TorchRL's own transform tests), on real MuJoCo HalfCheetah."""

import functools

import pytest
import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.envs import ParallelEnv, SerialEnv
from torchrl.envs.transforms import Compose, RewardScaling
from torchrl.envs.utils import check_env_specs

from drs_torchrl.envs.factory import make_family_env
from drs_torchrl.tasks import get_family
from drs_torchrl.transforms import ClassifierReward, DrSReward, SemiSparseReward, StageIndicator

pytestmark = pytest.mark.sim
SHAPES = {"observation": 17, "stage_indicators": 1}


def _drs():
    return DrSReward(1, ["observation", "stage_indicators"], SHAPES, formula="rescaled")


def _vice():
    return ClassifierReward(["observation"], {"observation": 17}, 1, method="vice_raq")


def _gail_stages():
    return ClassifierReward(
        ["observation", "stage_indicators"], SHAPES, 1, use_action=True, action_dim=6, stage_weight=1.0, method="gail"
    )


def _dense_shift():
    return RewardScaling(loc=-1.0, scale=1.0)


def _semi_sparse():
    return SemiSparseReward(1, offset=-1.0)


MAKERS = {
    "drs": _drs,
    "vice_raq": _vice,
    "gail_stages": _gail_stages,
    "dense_shift": _dense_shift,
    "semi_sparse": _semi_sparse,
}
LEARNED = ["drs", "vice_raq", "gail_stages"]
# the range each learned reward declares, worked out by hand: DrS rescaled with N = 1, alpha = 1/3, offset -2:
# (offset - alpha/N, offset + 1); the classifiers: log sigmoid of a logit clipped to [-10, 10] (log sigmoid(-10) =
# -10 - log(1 + e^-10)), up to 0, minus stage_weight * N for gail_stages
LOG_SIGMOID_MIN = -10.000045398899218
BOUNDS = {"drs": (-2 - 1 / 3, -1.0), "vice_raq": (LOG_SIGMOID_MIN, 0.0), "gail_stages": (LOG_SIGMOID_MIN - 1.0, 0.0)}


def _env(transform=None):
    ts = [transform] if transform is not None else []
    return make_family_env(get_family("half_cheetah"), "train", seed=0, max_episode_steps=20, transforms=ts)


def _seeded(maker):
    torch.manual_seed(0)
    return maker()


def _env_with(name):
    """A sub-env of a batched env, with its own copy of the transform (picklable for ParallelEnv)."""
    return _env(_seeded(MAKERS[name]))


@pytest.mark.slow
@pytest.mark.parametrize("name", MAKERS)
def test_single_env_and_inside_and_outside_batched_envs(name):
    maker = functools.partial(_seeded, MAKERS[name])
    t = maker()
    if name in BOUNDS:  # trained: the learned term in the reward (untrained, DrS's would be exactly -2 or -1)
        (t.discriminators if isinstance(t, DrSReward) else t.classifier).trained.fill_(True)
    e = _env(t)
    try:
        check_env_specs(e)
        if name in BOUNDS:  # the learned rewards declare their range in the reward spec
            lo, hi = BOUNDS[name]
            space = e.reward_spec.space
            assert (space.low.item(), space.high.item()) == pytest.approx((lo, hi), abs=1e-5)
            r = e.rollout(10)["next", "reward"]
            assert ((r >= lo) & (r <= hi)).all() and r.unique().numel() > 1, r.reshape(-1)
    finally:
        e.close()
    for batched in (SerialEnv, ParallelEnv):
        inside = batched(2, functools.partial(_env_with, name))  # the transform inside each sub-env
        try:
            check_env_specs(inside)
        finally:
            inside.close()
    outside = make_family_env(get_family("half_cheetah"), "train", seed=0, max_episode_steps=20, num_envs=2)
    outside.append_transform(maker())  # one transform over the batched env
    try:
        check_env_specs(outside)
        td = outside.rollout(3)
        assert td["next", "reward"].shape == (2, 3, 1)
    finally:
        outside.close()


@pytest.mark.parametrize("name", LEARNED)
def test_composed_on_a_replay_buffer_without_env_and_in_a_model(name):
    reward = _seeded(MAKERS[name])
    e = _env()
    try:
        data = e.rollout(6)
    finally:
        e.close()
    expected = reward.reward(data) if isinstance(reward, ClassifierReward) else reward.reward(data["next"])
    # composed (a Compose of a stage labeller and the reward, applied to transitions)
    composed = Compose(StageIndicator(["success"]), reward.clone())
    out = composed(data.clone())
    assert torch.allclose(out["next", "reward"], expected)
    # on a replay buffer: the reward is recomputed at sampling
    rb = ReplayBuffer(storage=LazyTensorStorage(10), transform=reward.clone(), batch_size=6)
    rb.extend(data.clone().exclude(("next", "reward")))
    sample = rb.sample()
    got = reward.reward(sample) if isinstance(reward, ClassifierReward) else reward.reward(sample["next"])
    assert torch.allclose(sample["next", "reward"], got)
    # no env: a bare TensorDict of transitions
    bare = reward.clone()(data.clone())
    assert torch.allclose(bare["next", "reward"], expected)
    # in a model
    model = nn.Sequential(reward.clone(), nn.Identity())
    assert torch.allclose(model(data.clone())["next", "reward"], expected)
    # a missing input is named
    with pytest.raises(KeyError, match="observation"):
        reward.clone()(
            TensorDict(
                {
                    "next": data["next"].exclude("observation"),
                    "action": data["action"],
                    "observation": data["observation"],
                    "stage": data["stage"],
                },
                batch_size=data.shape,
            )
        )


@pytest.mark.parametrize("name", LEARNED)
def test_dtype_casts_keep_the_reward_and_its_declared_dtype(name):
    """``.double()`` / ``.to(torch.bfloat16)`` / ``.float()`` of the transform (e.g. a whole model cast):
    the inputs follow the weights' dtype and the reward stays float32, as the reward spec declares."""
    reward = _seeded(MAKERS[name])
    e = _env()
    try:
        data = e.rollout(6)
    finally:
        e.close()
    reward.requires_grad_(False)
    (reward.discriminators if isinstance(reward, DrSReward) else reward.classifier).trained.fill_(True)
    expected = reward(data.clone())["next", "reward"]
    for dtype, tol in ((torch.float64, 1e-5), (torch.float32, 0.0), (torch.bfloat16, 0.05)):  # bf16 last: lossy
        got = reward.to(dtype)(data.clone())["next", "reward"]
        assert got.dtype == torch.float32
        assert torch.allclose(got, expected, atol=tol), dtype
