"""The make_* factories and the algo config's updater work on their own, as the docs show (real ManiSkill env)."""

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate


from drs_torchrl.apps.reward_registry import available_rewards, registry_entry
from drs_torchrl.rewards import is_learned, reward_setup
from drs_torchrl.tasks import family_from_config
from drs_torchrl.apps.cli import conf_dir
from drs_torchrl.apps.factories import make_envs, make_replay_buffer


@pytest.mark.sim
def test_factories_and_the_algo_updater_assemble_a_sac_update_on_a_family_env():
    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        cfg = compose("reuse", overrides=["env=turn_valve", "reward=semi_sparse", "algo.hidden=[16,16]"])
    family = family_from_config(cfg.env)
    env, eval_env, kwargs = make_envs(
        cfg.env, family, reward_setup(cfg.reward, "reuse"), torch.device("cpu"), seed=cfg.seed
    )
    try:
        assert kwargs["semi_sparse_reward"] and eval_env.batch_size == torch.Size([])
        replay = make_replay_buffer(cfg.algo.replay_buffer, None, torch.device("cpu"))
        updater = instantiate(cfg.algo.updater)(env, replay)  # SAC: actor, twin critics, SACLoss, optimisers
        replay.extend(env.rollout(8, updater.policy))  # outside no_grad: the env detaches the actions itself
        opts = updater.optimizers
        before = [p.clone() for p in opts["critic"].param_groups[0]["params"]]
        stats, rewards = updater.step()
        assert updater.updates == 1 and set(stats.keys()) >= {"loss_actor", "loss_qvalue", "alpha"}
        assert any(not torch.equal(b, p) for b, p in zip(before, opts["critic"].param_groups[0]["params"]))
        assert (replay.sample(4)["next", "reward"] <= 0).all()  # semi-sparse: k - N
    finally:
        env.close()
        eval_env.close()


def learner_of(factories, cfg):
    """``make_reward_learner`` as a run calls it (apps/build.py)."""
    return factories.make_reward_learner(
        cfg.reward,
        family_from_config(cfg.env),
        None,
        split=cfg.env.split,
        variant_overrides=None,
        seed=cfg.seed,
        reward_updates_per_update=cfg.algo.get("reward_updates_per_update"),
        device="cpu",
        precision="fp32",
        step_fn=None,
    )


@pytest.mark.parametrize(
    "algo, batch, utd, disc_steps, disc_batch",
    [
        ("sac_cpu", 256, 0.5, 1, 256),
        ("sac_cpu_utd025", 512, 0.25, 2, 256),
        ("sac_cpu_utd033", 384, 0.3333333333, 1.5, 256),
        ("sac_cpu_halfdisc", 256, 0.5, 0.5, 256),
        ("sac_cpu_utd033_halfdisc", 384, 0.3333333333, 0.75, 256),
        ("sac_paper", 1024, 0.5, 1, 1024),
        ("sac_paper_utd025", 2048, 0.25, 2, 1024),
    ],
)
def test_reward_learner_steps_follow_the_algo_config(algo, batch, utd, disc_steps, disc_batch, monkeypatch):
    """Fewer, larger SAC updates keep the discriminators' steps per env step (issue 12): each learned reward's
    learner steps ``algo.reward_updates_per_update`` times per RL update (one setting, in the algo config), and its
    batch per side comes from the algo config (``sac_paper``: the paper's 1024, Appendix E's one batch size); an
    explicit override wins."""
    from drs_torchrl.apps import factories

    seen = {}
    monkeypatch.setattr(factories, "new_reward_learner", lambda *a, **kw: seen.update(kw))
    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        learned = [n for n in available_rewards() if is_learned(registry_entry(n))]
        assert {"drs", "vice_raq", "gail", "gail_stages", "oril"} <= set(learned)
        for reward in learned:  # every learned reward of the registry (conf/reward/)
            cfg = compose("learn", overrides=[f"algo={algo}", f"reward={reward}"])
            assert "updates_per_sac_update" not in cfg.reward.disc, "the rate has one name, the algo config's"
            learner_of(factories, cfg)
            got = (cfg.algo.batch_size, cfg.algo.utd, seen["reward_updates_per_update"], cfg.reward.disc.batch_size)
            assert got == (batch, utd, disc_steps, disc_batch), reward
        cfg = compose(
            "learn", overrides=[f"algo={algo}", "algo.reward_updates_per_update=3", "reward.disc.batch_size=64"]
        )
        learner_of(factories, cfg)
        assert (seen["reward_updates_per_update"], cfg.reward.disc.batch_size) == (3, 64)
