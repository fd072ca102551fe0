"""The reward-learning core's baselines on problems whose answer is known (separable synthetic states),
their reward transform, and checkpoints; the CLI runs of each are in test_baselines_cli.py."""

import math

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import LazyTensorStorage, ReplayBuffer

from drs_torchrl.learners import (
    DemoDiscriminatorLearner,
    DrSLearner,
    OfflineClassifierLearner,
    SuccessClassifierLearner,
)
from drs_torchrl.transforms import ClassifierReward, DrSReward, RewardCheckpointError, load_reward

D = 4  # observation size of the synthetic problems


def states(n, *, good: bool, g=None):
    """Synthetic states: "good" ones have observation[0] > 0.5, the others < -0.5."""
    g = g or torch.Generator().manual_seed(0)
    x = torch.randn(n, D, generator=g) * 0.3
    x[:, 0] = (torch.rand(n, generator=g) + 0.5) * (1 if good else -1)
    stage = torch.full((n, 1), 1 if good else 0, dtype=torch.long)
    return TensorDict({"observation": x, "stage": stage, "success": stage.bool()}, batch_size=[n])


def transitions(n, *, good: bool):
    s, nxt = states(n, good=good), states(n, good=good)
    return TensorDict(
        {
            "observation": s["observation"],
            "stage": s["stage"],
            "action": torch.full((n, 2), 1.0 if good else -1.0),
            "next": nxt,
        },
        batch_size=[n],
    )


def reward(**kw):
    return ClassifierReward(["observation"], {"observation": D}, 1, **kw)


def test_classifier_reward_outputs_bounds_and_stage_term():
    r = reward(stage_weight=0.5, classifier_weight=2.0)
    td = states(8, good=True)
    # untrained: the classifier contributes its value at logit 0 (2 * log 0.5); success (k = N = 1): no stage cost
    assert torch.allclose(r.reward(td), torch.full((8, 1), 2 * math.log(0.5)))
    td0 = states(8, good=False)
    assert torch.allclose(r.reward(td0), torch.full((8, 1), 2 * math.log(0.5) - 0.5))  # k - N = -1
    r.classifier.trained.fill_(True)
    with torch.no_grad():
        r.classifier.net[-1].bias.fill_(100.0)  # logits clipped to 10
    lo, hi = r.reward_bounds()
    out = r.reward(torch.cat([td, td0]))
    assert (out >= lo - 1e-6).all() and (out <= hi + 1e-6).all() and hi == 0.0
    s = reward(output="sigmoid", offset=-1.0)
    assert s.reward_bounds() == (-1.0, 0.0)
    with pytest.raises(ValueError, match="output must be one of"):
        reward(output="exp")
    with pytest.raises(KeyError, match="reads \\(s, a\\)"):
        reward(use_action=True, action_dim=2).reward(td)
    # the stage term refuses a stage outside [0, N] as DrSReward does (it had scored stage 5 above success)
    bad = states(2, good=True)
    bad["stage"] = torch.tensor([[5], [-1]])
    with pytest.raises(ValueError, match=r"stage labels \('stage'\) must lie in \[0, 1\] .*got -1, 5"):
        r.reward(bad)


def test_vice_raq_separates_success_states_from_the_rest():
    r = reward()
    learner = SuccessClassifierLearner(r, batch_size=64, lr=1e-2)
    assert learner.update() is None  # no success state seen yet: nothing to learn
    for good in (False, True, False):
        batch = TensorDict({"next": states(200, good=good)}, batch_size=[200])
        learner.observe(batch, [])
    assert len(learner.positives) == 200 and len(learner.negatives) == 400
    for _ in range(200):
        stats = learner.update()
    assert float(stats["accuracy"]) > 0.95
    assert r.reward(states(50, good=True)).min() > r.reward(states(50, good=False)).max()


def test_oril_learns_demonstrations_against_random_states_offline():
    r = reward(output="sigmoid", offset=-1.0)
    demos = [states(30, good=True) for _ in range(3)]
    learner = OfflineClassifierLearner(r, demos=demos, offline_updates=200, batch_size=64, lr=1e-2)
    stats = learner.fit_offline(states(300, good=False))
    assert float(stats["accuracy"]) > 0.95 and learner.random_states == 300
    assert learner.update() is None  # frozen once RL starts
    good, bad = r.reward(states(50, good=True)), r.reward(states(50, good=False))
    assert good.min() > -0.1 and bad.max() < -0.9  # D - 1: about 0 on demonstrations, about -1 elsewhere
    with pytest.raises(ValueError, match="demos.path"):
        OfflineClassifierLearner(reward(), demos=[])


@pytest.mark.parametrize("use_action", [True, False])
def test_gail_tells_demonstrations_from_agent_transitions(use_action):
    r = reward(use_action=use_action, action_dim=2 if use_action else None)
    demo = transitions(100, good=True)
    ep = TensorDict(
        {**demo["next"].to_dict(), "action": demo["action"], "state": demo.select("observation", "stage")},
        batch_size=[100],
    )
    learner = DemoDiscriminatorLearner(r, demos=[ep], batch_size=64, lr=1e-2)
    replay = ReplayBuffer(storage=LazyTensorStorage(1000))
    learner.attach(replay)
    assert learner.update() is None  # no agent data yet
    replay.extend(transitions(300, good=False))
    for _ in range(150):
        stats = learner.update()
    assert float(stats["accuracy"]) > 0.95
    assert r.reward(transitions(50, good=True)).min() > r.reward(transitions(50, good=False)).max()
    with pytest.raises(ValueError, match="lack \\['action', 'state'\\]"):
        DemoDiscriminatorLearner(reward(use_action=True, action_dim=2), demos=[states(5, good=True)])


def test_gail_corrects_a_confidently_wrong_discriminator():
    """Agent transitions scored as demonstrations beyond the reward's logit clip (12 > 10) still move the
    discriminator: its loss sees the unclipped probability."""
    r = reward()
    learner = DemoDiscriminatorLearner(r, demos=[states(100, good=True)], batch_size=64, lr=1e-2)
    replay = ReplayBuffer(storage=LazyTensorStorage(1000))
    learner.attach(replay)
    replay.extend(transitions(300, good=False))
    with torch.no_grad():
        r.classifier.net[-1].weight.zero_()
        r.classifier.net[-1].bias.fill_(12.0)  # every input, the agent's included, scored "demonstration"
    learner.update()
    assert float(r.classifier.net[-1].bias) < 12.0


def test_classifier_checkpoint_round_trip_and_reuse_checks(tmp_path):
    r = reward(use_action=True, action_dim=2, method="gail", metadata={"family": "synthetic"})
    r.classifier.trained.fill_(True)
    td = transitions(20, good=True)
    path = r.save(tmp_path / "reward.pt", frames=7)
    back = load_reward(path)
    assert isinstance(back, ClassifierReward) and back.method == "gail" and back.metadata["frames"] == 7
    assert torch.equal(back.reward(td), r.reward(td))
    staged = ClassifierReward.from_checkpoint(path, stage_weight=2.0)
    assert torch.allclose(staged.reward(td), r.reward(td))  # stage k = N: no stage cost
    with pytest.raises(RewardCheckpointError, match="not a DrS reward"):
        DrSReward.from_checkpoint(path)
    drs = DrSReward(1, ["observation"], {"observation": D})
    with pytest.raises(RewardCheckpointError, match="not a classifier reward"):
        ClassifierReward.from_checkpoint(drs.save(tmp_path / "drs.pt"))
    assert isinstance(load_reward(tmp_path / "drs.pt"), DrSReward)
    from torchrl.data import Bounded, Composite, Unbounded

    obs = Composite(observation=Unbounded(shape=(5,)), stage=Unbounded(shape=(1,), dtype=torch.long))
    with pytest.raises(RewardCheckpointError, match="size 4.*size 5.*actions of size 2.*size 3"):
        r.check_compatible(obs, family="synthetic", action_spec=Bounded(-1, 1, shape=(3,)))


def test_reuse_refuses_a_checkpoint_of_another_method(tmp_path):
    from omegaconf import OmegaConf

    from drs_torchrl.apps.reward_registry import with_builders
    from drs_torchrl.rewards import reward_setup

    def node(**settings):  # a reward config node as composed from conf/reward/<name>.yaml
        return with_builders(OmegaConf.create(settings))

    path = reward(method="vice_raq").save(tmp_path / "v.pt")
    cfg = node(name="gail_stages", checkpoint=str(path), stage_weight=1.0, classifier_weight=1.0)
    with pytest.raises(RewardCheckpointError, match="learned by reward=vice_raq; use reward=vice_raq"):
        reward_setup(cfg, "reuse")
    with pytest.raises(ValueError, match="needs reward.checkpoint"):
        reward_setup(node(name="oril", checkpoint=None), "reuse")
    assert reward_setup(node(name="vice_raq", checkpoint=str(path)), "reuse").frozen.method == "vice_raq"


def episode(n, *, success: bool, g=None):
    """One episode of synthetic states under ``"next"``: a success ends on a good (stage-1) state."""
    nxt = states(n, good=False, g=g)
    if success:
        nxt[-1] = states(1, good=True, g=g)[0]
    return TensorDict({"next": nxt.select("observation", "stage")}, batch_size=[n])


@pytest.mark.parametrize("file_successes", [True, False])
def test_drs_learner_files_episodes_by_stage_and_separates_them(file_successes):
    """One stage: successful episodes (and demos) against failed ones; the learned reward ranks the
    success states above the failure states. ``file_successes=False`` keeps the agent's successes
    out of the top buffer (demonstrations only) but still counts them for the early stop."""
    torch.manual_seed(0)
    r = DrSReward(1, ["observation"], {"observation": D}, formula="rescaled")
    demo = states(5, good=True)
    learner = DrSLearner(
        r, batch_size=64, lr=3e-3, demos=[demo.select("observation", "stage")], file_successes=file_successes
    )
    g = torch.Generator().manual_seed(1)
    eps = [episode(6, success=i % 2 == 0, g=g) for i in range(20)]
    learner.observe(None, eps)
    counts = learner.stage_buffers.stage_counts().tolist()
    assert counts[0] == 10 * 6  # failures filed whole (one stage: nothing to cut)
    assert counts[1] == 5 + (10 * 6 if file_successes else 0)
    assert learner.stage_buffers.episodes_per_stage.tolist() == [10, 1 + (10 if file_successes else 0)]
    assert learner.loss.beyond_rates()[0] == pytest.approx(0.5)  # successes count either way
    accuracy = [float(learner.update()["accuracy_0"]) for _ in range(200)]
    assert learner.updates == 200
    last = sum(accuracy[-50:]) / 50  # the mean over the last 50 batches (one batch's varies by +-0.1)
    if not file_successes:  # demos only: positives (good states) and negatives separate cleanly
        assert last > 0.95
    else:
        # the agent's successes filed: their 50 failure-like early states sit among the 65 positives, so the best
        # a classifier can do is 0.5 * 1 (negatives) + 0.5 * 15/65 (the good positives) = 0.615, chance 0.5
        assert 0.59 < last < 0.65, last
    good = states(200, good=True, g=torch.Generator().manual_seed(5))
    with torch.no_grad():
        assert (r.discriminators(r.features(good)) > 0).all()  # every good state scored "got beyond stage 0"
    td = TensorDict(
        {
            "next": {
                "observation": torch.cat([states(50, good=True)["observation"], states(50, good=False)["observation"]]),
                "stage": torch.zeros(100, 1, dtype=torch.long),
                "reward": torch.zeros(100, 1),
            }
        },
        batch_size=[100],
    )
    rew = r(td)["next", "reward"].reshape(-1)
    assert rew[:50].mean() > rew[50:].mean()
    state = learner.state_dict()
    fresh = DrSLearner(DrSReward(1, ["observation"], {"observation": D}, formula="rescaled"), batch_size=64)
    fresh.load_state_dict(state)
    assert fresh.updates == 200 and torch.equal(fresh.reward(td)["next", "reward"], r(td)["next", "reward"])


@pytest.mark.parametrize(
    "rate, expected", [(0.5, [0, 1, 0, 1, 0, 1]), (1.5, [1, 2, 1, 2, 1, 2]), (1, [1] * 6), (2, [2] * 6)]
)
def test_fractional_reward_learner_steps_carry_over_and_survive_a_checkpoint(rate, expected):
    """``reward_updates_per_update`` may be fractional (issue 12's fewer-updates levers): 0.5 is one
    discriminator step every second RL update, 1.5 one and two in turn; the remainder is saved with
    the learner, so a resumed run keeps the schedule."""
    torch.manual_seed(0)
    learner = DrSLearner(
        DrSReward(1, ["observation"], {"observation": D}, formula="rescaled"),
        batch_size=16,
        reward_updates_per_update=rate,
        demos=[states(5, good=True).select("observation", "stage")],
    )
    g = torch.Generator().manual_seed(1)
    learner.observe(None, [episode(6, success=i % 2 == 0, g=g) for i in range(4)])
    steps = []
    for i in range(6):
        if i == 3:  # a checkpoint round trip mid-schedule
            state = learner.state_dict()
            learner = DrSLearner(
                DrSReward(1, ["observation"], {"observation": D}, formula="rescaled"),
                batch_size=16,
                reward_updates_per_update=rate,
                demos=[states(5, good=True).select("observation", "stage")],
            )
            learner.observe(None, [episode(6, success=i % 2 == 0, g=g) for i in range(4)])
            learner.load_state_dict(state)
        before = learner.updates
        learner.update()
        steps.append(learner.updates - before)
    assert steps == expected
    assert learner.updates == sum(expected)
    with pytest.raises(ValueError, match="must be > 0"):
        DrSLearner(DrSReward(1, ["observation"], {"observation": D}), reward_updates_per_update=0)
