"""The RL updaters of Algorithm 1: each one's step and update on synthetic TensorDicts (SAC, DQN, PPO; no simulator),
the fractional update budget every updater uses, and PPO in phase 1 on a real ManiSkill family, its reward learner
training beside it."""

import functools
import io

import pandas as pd
import pytest
import torch
from hydra import compose, initialize_config_dir
from tensordict import TensorDict
from torchrl.data import Bounded, Composite, LazyTensorStorage, OneHot, ReplayBuffer, Unbounded
from torchrl.objectives import HardUpdate, SACLoss, SoftUpdate

from drs_torchrl.runtime.checkpoint import TrainingStateError
from drs_torchrl.models import load_policy
from drs_torchrl.apps.cli import conf_dir
from drs_torchrl.apps.build import Run
from drs_torchrl.transforms import DrSReward
from drs_torchrl.updaters import UpdateBudget
from drs_torchrl.updaters.dqn import make_dqn_updater
from drs_torchrl.updaters.ppo import make_ppo_updater
from drs_torchrl.updaters.sac import make_sac_updater

TINY_PPO = [
    "env=turn_valve",
    "algo=ppo",
    "algo.frames_per_batch=500",
    "algo.batch_size=250",
    "algo.epochs=2",
    "algo.hidden=[32,32]",
    "eval.episodes=1",
    "eval.interval=100000",
    "logger.interval=500",
    "checkpoint_interval=1000",
    "logger.progress_bar=false",
    "logger.tensorboard=false",
    "reward.disc.batch_size=32",
    "stop_at_success=null",
    "demos.path=null",
    "+env.variant_overrides.turning_thresh=0.003",  # some reach the first stage by chance: both classes of D_0
]


def config(*extra):
    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        return compose("learn", overrides=[*TINY_PPO, *extra])


@pytest.mark.slow
@pytest.mark.sim
def test_ppo_phase_1_trains_the_reward_learner_and_rewards_its_batches_with_it(tmp_path):
    summary = Run(config("total_frames=2000"), "learn", tmp_path).run()
    # 4 batches x 2 epochs x 2 minibatches; the reward learner is offered one step per PPO step
    assert summary["algo"] == "ppo" and summary["frames"] == 2000 and summary["updates"] == 16
    assert summary["disc_updates"] >= 1
    rows = pd.read_csv(tmp_path / "train.csv")
    assert {"loss_objective", "loss_critic", "disc_loss_0"} <= set(rows.columns)
    # the batches were rewarded by the learned reward before GAE: the rescaled DrS reward of stage 0 or 1 is below
    # -1 (the env's own phase-1 reward would be 0 / 1)
    assert (rows["reward_max"].dropna() < -1).all()

    # the policy loads like a SAC policy (same actor network), and the run resumes from its state
    run = Run(config("total_frames=2500"), "learn", tmp_path, resume=True)
    try:
        actor, meta = load_policy(tmp_path, run.env.observation_spec, run.env.action_spec, family="turn_valve")
        assert meta["algo"] == "ppo" and run.frames == 2000 and run.updater.updates == 16
    finally:
        run.close()
    summary = Run(config("total_frames=2500"), "learn", tmp_path, resume=True).run()
    assert summary["frames"] == 2500 and summary["resumed_from"] == 2000

    # a PPO state is not resumed by another algorithm
    with pytest.raises(TrainingStateError, match="training state is ppo's.*sac"):
        with initialize_config_dir(config_dir=conf_dir(), version_base=None):
            sac = compose("learn", overrides=["env=turn_valve", "algo.hidden=[32,32]", "logger.tensorboard=false"])
        Run(sac, "learn", tmp_path, resume=True)


def test_update_budget_carries_fractions_over():
    budget = UpdateBudget(1 / 3)  # sac_cpu_utd033: a third of an update per env step, 64-step batches
    takes = [budget.take(64) for _ in range(300)]
    assert set(takes) == {21, 22} and sum(takes) == 6400 and 0 <= budget.owed < 1
    half = UpdateBudget(0.5)
    assert [half.take(3) for _ in range(4)] == [1, 2, 1, 2]
    with pytest.raises(ValueError, match="> 0"):
        UpdateBudget(0)


# ---------------------------------------------------------------------------------------------- each updater's step
# on synthetic TensorDicts with small specs (no simulator): what one optimisation step changes, the updates a batch
# pays for, the learner's steps, and the state a resumed run reloads

OBS, STAGES, ACT = 9, 2, 3


def transitions(n: int, seed: int = 0, *, one_hot: int = 0) -> TensorDict:
    """``n`` transitions of a fake env: observation, stage indicators, an action (continuous in [-1, 1], or one-hot
    over ``one_hot`` actions), and the next state's reward (its index: each transition's own), done, terminated."""
    g = torch.Generator().manual_seed(seed)
    done = torch.rand(n, 1, generator=g) < 0.1
    action = (
        torch.nn.functional.one_hot(torch.randint(0, one_hot, (n,), generator=g), one_hot).bool()
        if one_hot
        else torch.rand(n, ACT, generator=g) * 2 - 1
    )
    return TensorDict(
        {
            "observation": torch.randn(n, OBS, generator=g),
            "stage_indicators": torch.zeros(n, STAGES),
            "action": action,
            "next": {
                "observation": torch.randn(n, OBS, generator=g),
                "stage_indicators": torch.zeros(n, STAGES),
                "stage": torch.zeros(n, 1, dtype=torch.long),
                "reward": torch.arange(n, dtype=torch.float32).unsqueeze(-1),
                "done": done,
                "terminated": done,
                "truncated": torch.zeros(n, 1, dtype=torch.bool),
            },
        },
        batch_size=[n],
    )


class Log:
    """The loop's update log, as the updaters call it: ``("update", stats, rewards)`` and ``("learner", stats)``."""

    def __init__(self):
        self.calls = []

    def update(self, stats, rewards=None):
        self.calls.append(("update", stats, rewards))

    def learner(self, stats):
        self.calls.append(("learner", stats))


def saved_and_loaded(state: dict) -> dict:
    """Through a file, as a resumed run reads it (weights only): the optimisers' moments are then copies, not the
    live tensors of the updater that wrote them."""
    buf = io.BytesIO()
    torch.save(state, buf)
    buf.seek(0)
    return torch.load(buf, weights_only=True)


def learner_step():
    def step():
        return TensorDict({"loss_0": torch.tensor(0.5)}, [])

    return step


class ContinuousEnv:
    observation_spec = Composite(observation=Unbounded((OBS,)), stage_indicators=Unbounded((STAGES,)))
    action_spec = Bounded(-1.0, 1.0, (ACT,))


def sac_updater(seed=0, *, transform=None, hidden=(16, 16), utd=0.5, learning_starts=0, vmap=False, **kw):
    torch.manual_seed(seed)
    replay = ReplayBuffer(storage=LazyTensorStorage(1000), batch_size=32, transform=transform)
    u = make_sac_updater(
        ContinuousEnv(),
        replay,
        loss=functools.partial(
            SACLoss, num_qvalue_nets=2, loss_function="l2", alpha_init=1.0, deactivate_vmap=not vmap
        ),
        optim=functools.partial(torch.optim.Adam, lr=3e-4, fused=kw.pop("fused", False)),
        target_update=functools.partial(SoftUpdate, tau=0.005),
        hidden=list(hidden),
        policy_in_keys=["observation", "stage_indicators"],
        gamma=0.8,
        utd=utd,
        learning_starts=learning_starts,
        **kw,
    )
    return u


def test_a_sac_step_trains_actor_critics_and_alpha_and_moves_the_targets_by_tau():
    u = sac_updater()
    u.extend(transitions(200))
    loss = u.loss
    before = {
        "actor": loss.actor_network_params.clone(),
        "critic": loss.qvalue_network_params.clone(),
        "target": loss.target_qvalue_network_params.clone(),
        "log_alpha": loss.log_alpha.detach().clone(),
    }
    stats, rewards = u.step()
    assert u.updates == 1
    assert set(stats.keys()) == {"loss_actor", "loss_qvalue", "loss_alpha", "alpha", "entropy"}
    assert all(bool(torch.isfinite(stats[k]).all()) for k in stats.keys())
    for name, now in (("actor", loss.actor_network_params), ("critic", loss.qvalue_network_params)):
        assert all(not torch.equal(before[name][k], now[k]) for k in now.keys(True, True)), name
    assert not torch.equal(before["log_alpha"], loss.log_alpha.detach())
    # SoftUpdate(tau=0.005): each target moves 0.5 % of the way to the critic it follows, after the critic's step
    critic, target = loss.qvalue_network_params, loss.target_qvalue_network_params
    for k in target.keys(True, True):
        expected = 0.995 * before["target"][k] + 0.005 * critic[k]
        assert torch.allclose(target[k], expected, atol=1e-7), k
        assert not torch.equal(target[k], before["target"][k])
    # the rewards it trained on: 32 of the stored transitions' own (reward = index, each at most once)
    assert rewards.shape == (32, 1) and set(rewards.reshape(-1).tolist()) <= set(range(200))
    assert rewards.reshape(-1).unique().numel() > 16  # drawn across the buffer, not one transition repeated


@pytest.mark.sim  # not a simulator: torch.compile's minute of tracing, kept out of the fast tier
@pytest.mark.slow
def test_sac_compiled_whole_compiles_once_and_learns_as_eager_does(monkeypatch):
    """``algo.compile=update`` (issue 64): loss, backward, Adam steps and target update as one compiled function,
    compiled once for a run (no recompilation over many updates) and, on the same batches and the same random
    numbers, the losses and weights of eager updates (to float rounding; inductor's fused kernels reorder sums)."""
    import torch._dynamo
    import torch._inductor.config
    from torch._dynamo.utils import counters

    monkeypatch.setattr(torch._inductor.config, "fallback_random", True)  # eager's random numbers in the graph
    torch._dynamo.reset()
    counters.clear()
    # the config's fused Adam and one-after-the-other critics: compile=update takes the plain Adam and the vmap
    compiled = sac_updater(seed=1, compile="update", fused=True)
    eager = sac_updater(seed=1, vmap=True)
    assert compiled.compile_scope == "update" and not compiled.optimizers["critic"].defaults["fused"]
    data = transitions(400)
    for u in (eager, compiled):
        u.extend(data)
    for i in range(4):
        torch.manual_seed(100 + i)
        want, _ = eager.step()
        torch.manual_seed(100 + i)
        got, _ = compiled.step()
        for k in ("loss_actor", "loss_qvalue", "loss_alpha", "alpha"):
            torch.testing.assert_close(got[k], want[k], rtol=1e-4, atol=1e-5)
    for name in ("actor_network_params", "qvalue_network_params", "target_qvalue_network_params"):
        a, b = getattr(compiled.loss, name), getattr(eager.loss, name)
        for k, v in a.items(True, True):
            torch.testing.assert_close(v, b[k], rtol=1e-4, atol=1e-5)
    graphs = counters["stats"]["unique_graphs"]
    assert graphs > 0  # it was compiled
    for _ in range(25):
        compiled.step()
    assert counters["stats"]["unique_graphs"] == graphs, "the whole update recompiled"
    assert compiled.updates == 29


def test_algo_compile_takes_a_scope_and_update_refuses_low_precision():
    from drs_torchrl.updaters.sac import compile_scope

    assert [compile_scope(v) for v in (False, None, True, "loss", "Update")] == [None, None, "loss", "loss", "update"]
    with pytest.raises(ValueError, match="algo.compile must be false, true .= loss., loss or update, got 'off'"):
        compile_scope("off")
    with pytest.raises(ValueError, match="use algo.precision=fp32 with it .got bf16."):
        sac_updater(compile="update", precision="bf16")


def test_a_sac_step_trains_on_the_reward_its_replay_buffer_recomputes_at_sampling():
    reward = DrSReward(STAGES, ["observation"], {"observation": OBS}, formula="rescaled")
    reward.discriminators.trained.fill_(True)
    u = sac_updater(transform=reward)
    data = transitions(200)
    u.extend(data)
    _, rewards = u.step()
    possible = reward.reward(data["next"]).reshape(-1)  # what each stored next state earns under the reward now
    assert rewards.shape == (32, 1) and rewards.max() < -1.5  # not the stored 0..199: recomputed
    assert all(bool(torch.isclose(possible, r).any()) for r in rewards.reshape(-1))


def test_sac_update_takes_the_steps_a_batch_pays_for_with_a_learner_step_before_each():
    u = sac_updater(utd=0.5, learning_starts=100)
    u.extend(transitions(64))
    log = Log()
    assert u.update(64, 64, learner_step(), log) == 0 and u.updates == 0 and u.budget.owed == 0.0  # before 100
    u.extend(transitions(64, seed=1))
    assert u.update(64, 128, learner_step(), log) == 32 and u.updates == 32
    assert [c[0] for c in log.calls] == ["learner", "update"] * 32
    assert all(c[2].shape == (32, 1) for c in log.calls if c[0] == "update")
    assert u.update(3, 131, None, log) == 1 and u.budget.owed == 0.5  # 1.5 owed: one taken, a half carried
    assert [c[0] for c in log.calls[64:]] == ["update"]  # phase 2: no learner


def test_a_sac_state_reloads_to_the_same_next_step():
    a = sac_updater(seed=0)
    data = transitions(200)
    a.extend(data)
    for _ in range(3):
        a.step()
    a.budget.owed = 0.25
    b = sac_updater(seed=1)  # other initial weights
    b.extend(data)
    b.load_state_dict(saved_and_loaded(a.state_dict()))
    assert b.updates == 3 and b.budget.owed == 0.25
    torch.manual_seed(7)
    stats_a, rewards_a = a.step()
    torch.manual_seed(7)
    stats_b, rewards_b = b.step()
    assert torch.equal(rewards_a, rewards_b)
    assert all(torch.equal(stats_a[k], stats_b[k]) for k in stats_a.keys())
    for k, v in a.loss.state_dict().items():
        assert torch.equal(v, b.loss.state_dict()[k]), k


def test_a_sac_policy_checkpoint_starts_another_updater_and_a_misfit_is_named():
    a = sac_updater(seed=0)
    a.extend(transitions(200))
    a.step()
    b = sac_updater(seed=1)
    ck = a.policy_checkpoint()
    assert b.init_from(ck) == []
    td = transitions(8, seed=3).select("observation", "stage_indicators")
    out_a, out_b = a.actor(td.clone()), b.actor(td.clone())
    assert torch.equal(out_a["loc"], out_b["loc"]) and torch.equal(out_a["scale"], out_b["scale"])
    for params in ("qvalue_network_params", "target_qvalue_network_params"):
        got = getattr(b.loss, params)
        for k, v in a.loss.qvalue_network_params.items(True, True):
            assert torch.equal(got[k], v), (params, k)
    assert torch.equal(b.loss.log_alpha, a.loss.log_alpha)
    wide = sac_updater(hidden=(32, 32))
    (problem,) = wide.init_from(ck)
    assert "hidden [16, 16]" in problem and "hidden [32, 32]" in problem
    assert wide.init_from({k: v for k, v in ck.items() if k != "qvalue_params"} | {"hidden": [32, 32]}) == [
        "it holds no critics"
    ]


class DiscreteEnv:
    observation_spec = Composite(observation=Unbounded((OBS,)))
    action_spec = OneHot(4, dtype=torch.bool)


def dqn_updater(seed=0, **kw):
    torch.manual_seed(seed)
    settings = dict(
        optim=functools.partial(torch.optim.Adam, lr=1e-3),
        hidden=[16],
        gamma=0.9,
        target_update=functools.partial(HardUpdate, value_network_update_interval=2),
        eps_init=1.0,
        eps_end=0.1,
        eps_anneal_steps=100,
        utd=0.25,
        learning_starts=64,
    )
    return make_dqn_updater(
        DiscreteEnv(), ReplayBuffer(storage=LazyTensorStorage(1000), batch_size=32), **{**settings, **kw}
    )


def test_dqn_update_steps_then_learner_steps_after_learning_starts_and_anneals_epsilon():
    u = dqn_updater()
    log = Log()
    u.extend(transitions(64, one_hot=4))
    assert u.update(32, 32, learner_step(), log) == 0 and not log.calls  # before learning_starts: nothing owed
    qnet = {k: v.clone() for k, v in u.actor.state_dict().items()}
    assert u.update(64, 96, learner_step(), log) == 16 and u.updates == 16
    assert [c[0] for c in log.calls] == ["update", "learner"] * 16  # learner_after: the order every maze run used
    stats, rewards = log.calls[0][1], log.calls[0][2]
    assert set(stats.keys()) == {"dqn_loss"} and bool(torch.isfinite(stats["dqn_loss"]))
    assert rewards.shape == (32, 1) and set(rewards.reshape(-1).tolist()) <= set(range(64))
    assert any(not torch.equal(qnet[k], v) for k, v in u.actor.state_dict().items())
    # HardUpdate(2): the target is the online network right after every third step (its counter runs 0, 1, 2)
    online = dict(u.loss.value_network_params.items(True, True))
    target = dict(u.loss.target_value_network_params.items(True, True))
    assert u.target_updater.counter == 16 % 3 and any(not torch.equal(online[k], target[k]) for k in online)
    while u.target_updater.counter != 0:
        u.step()
    target = dict(u.loss.target_value_network_params.items(True, True))
    assert all(torch.equal(v, target[k]) for k, v in u.loss.value_network_params.items(True, True))
    # epsilon-greedy anneals per collected env step: 1.0 -> 0.1 over 100
    u.after_collect(50)
    assert float(u.explore.eps) == pytest.approx(0.55)
    u.after_collect(100)
    assert float(u.explore.eps) == pytest.approx(0.1)


def test_a_dqn_state_reloads_epsilon_target_counter_and_budget():
    a = dqn_updater(seed=0)
    data = transitions(64, one_hot=4)
    a.extend(data)
    a.update(6, 70, None, Log())  # 1.5 owed: one step, a half carried
    a.after_collect(30)
    b = dqn_updater(seed=1)
    b.extend(data)
    b.load_state_dict(saved_and_loaded(a.state_dict()))
    assert b.updates == 1 and b.budget.owed == 0.5 and b.target_updater.counter == a.target_updater.counter == 1
    assert float(b.explore.eps) == pytest.approx(float(a.explore.eps)) and float(a.explore.eps) < 1.0
    torch.manual_seed(3)
    sa, _ = a.step()
    torch.manual_seed(3)
    sb, _ = b.step()
    assert torch.equal(sa["dqn_loss"], sb["dqn_loss"])
    assert set(a.policy_checkpoint()) == {"qnet"}


def ppo_batch(u, n=64, seed=0, one_hot=0):
    """A collected batch: the policy's own actions and log-probabilities (what PPO's ratio reads)."""
    td = transitions(n, seed, one_hot=one_hot)
    with torch.no_grad():
        u.actor(td)
    return td


def ppo_updater(env=None, reward=None):
    torch.manual_seed(0)
    return make_ppo_updater(
        env or ContinuousEnv(),
        optim=functools.partial(torch.optim.Adam, lr=3e-4),
        hidden=[16, 16],
        policy_in_keys=["observation", "stage_indicators"] if env is None else ["observation"],
        gamma=0.9,
        lmbda=0.95,
        epochs=2,
        minibatch_size=16,
        reward=reward,
        precision="fp32",  # an off-policy argument every updater is handed: ignored
    )


def test_ppo_trains_each_batch_for_its_epochs_once_with_the_learner_first_and_the_reward_fixed():
    def reward(batch):  # a learned reward: rewrites the batch's rewards before the advantages
        batch.set(("next", "reward"), torch.full_like(batch.get(("next", "reward")), -1.25))

    u = ppo_updater(reward=reward)
    log = Log()
    assert u.update(64, 64, learner_step(), log) == 0  # nothing collected yet
    params = {k: v.clone() for k, v in u.loss.named_parameters()}
    u.extend(ppo_batch(u))
    # 2 epochs x 64 // 16 minibatches; the learner's 8 steps come first: the reward is then fixed for the epochs
    assert u.update(64, 64, learner_step(), log) == 8 and u.updates == 8
    assert [c[0] for c in log.calls] == ["learner"] * 8 + ["update"] * 8
    updates = [c for c in log.calls if c[0] == "update"]
    assert torch.equal(updates[0][2], torch.full((64,), -1.25)) and all(c[2] is None for c in updates[1:])
    assert {"loss_objective", "loss_critic", "kl_approx", "clip_fraction"} <= set(updates[0][1].keys())
    assert all(bool(torch.isfinite(c[1][k])) for c in updates for k in c[1].keys())
    assert any(not torch.equal(params[k], v) for k, v in u.loss.named_parameters())
    assert u.update(64, 128, learner_step(), log) == 0 and u.updates == 8  # the batch is dropped once trained on
    state = u.state_dict()
    assert state["updates"] == 8 and state["owed_updates"] == 0.0
    other = ppo_updater()
    other.load_state_dict(saved_and_loaded(state))
    assert other.updates == 8
    assert all(torch.equal(v, dict(u.loss.named_parameters())[k]) for k, v in other.loss.named_parameters())
    assert set(u.policy_checkpoint()) == {"policy_in_keys", "hidden", "actor"}


def test_ppo_over_one_hot_actions_is_a_categorical_policy():
    u = ppo_updater(env=DiscreteEnv())
    batch = ppo_batch(u, one_hot=4)
    assert batch["action"].shape == (64, 4) and (batch["action"].sum(-1) == 1).all()  # one action each
    u.extend(batch)
    log = Log()
    assert u.update(64, 64, None, log) == 8 and [c[0] for c in log.calls] == ["update"] * 8
    assert torch.equal(log.calls[0][2], torch.arange(64, dtype=torch.float32))  # the env's rewards, as collected
