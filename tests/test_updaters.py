"""The loop of Algorithm 1 with another RL algorithm: PPO (TorchRL's ClipPPOLoss + GAE) in phase 1 on a real
ManiSkill family, its reward learner training beside it; and the fractional update budget every updater uses."""

import pandas as pd
import pytest
from hydra import compose, initialize_config_dir

from drs_torchrl.checkpoint import TrainingStateError
from drs_torchrl.models import load_policy
from drs_torchrl.apps.cli import conf_dir
from drs_torchrl.apps.build import Run
from drs_torchrl.updaters import UpdateBudget

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
    assert set(takes) == {21, 22} and 6399 <= sum(takes) <= 6400 and 0 <= budget.owed < 1
    half = UpdateBudget(0.5)
    assert [half.take(3) for _ in range(4)] == [1, 2, 1, 2]
    with pytest.raises(ValueError, match="> 0"):
        UpdateBudget(0)
