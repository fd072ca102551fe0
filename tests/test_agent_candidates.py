"""The agent candidates of issue 64 (conf/algo/sac_ln*, sac_ens10_ln): each is one algo overlay that composes, builds
the networks it names, trains on synthetic batches, and writes a policy.pt that drs-eval's loader rebuilds; a policy
of one architecture is refused by a run of another (init_from=). No simulator."""

from __future__ import annotations

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from tensordict import TensorDict
from torch import nn
from torchrl.data import Bounded, Composite, LazyTensorStorage, ReplayBuffer, Unbounded

from drs_torchrl.apps.cli import conf_dir
from drs_torchrl.models import load_policy

OBS, ACT = 42, 8


class Env:
    observation_spec = Composite(observation=Unbounded((OBS,)), stage_indicators=Unbounded((3,)))
    action_spec = Bounded(-1.0, 1.0, (ACT,))


def batch(n: int, seed: int = 0) -> TensorDict:
    g = torch.Generator().manual_seed(seed)
    nxt = {
        "observation": torch.randn(n, OBS, generator=g),
        "stage_indicators": torch.rand(n, 3, generator=g).round(),
        "reward": torch.randn(n, 1, generator=g),
        "done": torch.zeros(n, 1, dtype=torch.bool),
        "terminated": torch.zeros(n, 1, dtype=torch.bool),
    }
    return TensorDict(
        {
            "observation": torch.randn(n, OBS, generator=g),
            "stage_indicators": torch.rand(n, 3, generator=g).round(),
            "action": torch.rand(n, ACT, generator=g) * 2 - 1,
            "next": nxt,
        },
        [n],
    )


def updater(algo: str, *extra: str):
    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        cfg = compose("learn", overrides=[f"algo={algo}", "algo.hidden=[32,32]", "algo.learning_starts=0", *extra])
    rb = ReplayBuffer(storage=LazyTensorStorage(1000), batch_size=int(cfg.algo.batch_size))
    rb.extend(batch(300))
    torch.manual_seed(0)
    return cfg, instantiate(cfg.algo.updater)(Env(), rb, device="cpu", precision="fp32")


def layer_norms(module: nn.Module) -> int:
    return sum(isinstance(m, nn.LayerNorm) for m in module.modules())


def assert_policy_file_rebuilds_the_actor(u, tmp_path) -> None:
    """policy.pt as the run writes it: drs-eval's loader rebuilds the same actor (normalisations included) and a run of
    the same algo fine-tunes from it."""
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    ck = {"format": "drs-torchrl/policy", "family": "pick_cube", **u.policy_checkpoint()}
    torch.save(ck, tmp_path / "policy.pt")
    actor, _ = load_policy(tmp_path / "policy.pt", Env.observation_spec, Env.action_spec, family="pick_cube")
    td = TensorDict({"observation": torch.randn(5, OBS), "stage_indicators": torch.zeros(5, 3)}, [5])
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        assert torch.allclose(actor(td.clone())["action"], u.actor(td.clone())["action"])
    assert u.init_from(ck) == []


@pytest.mark.parametrize(
    "algo, critic_ln, actor_ln, critics, batch_size, utd",
    [
        ("sac_cpu", 0, 0, 2, 256, 0.5),
        ("sac_ln", 2, 0, 2, 256, 0.5),
        ("sac_ln_all", 2, 2, 2, 256, 0.5),
        ("sac_ens10_ln", 2, 0, 10, 256, 0.5),
        ("sac_ln_utd1_b128", 2, 0, 2, 128, 1.0),
    ],
)
def test_each_candidate_builds_what_it_names_and_trains(algo, critic_ln, actor_ln, critics, batch_size, utd, tmp_path):
    cfg, u = updater(algo)
    assert cfg.algo.name == algo and int(cfg.algo.batch_size) == batch_size and float(cfg.algo.utd) == utd
    assert layer_norms(u.qvalue) == critic_ln and layer_norms(u.actor) == actor_ln  # one per hidden layer
    assert int(u.loss.num_qvalue_nets) == critics
    before = [p.detach().clone() for p in u.loss.qvalue_network_params.values(True, True)]
    for _ in range(3):
        stats, _ = u.step()
    assert all(bool(torch.isfinite(stats[k])) for k in ("loss_actor", "loss_qvalue", "loss_alpha"))
    after = list(u.loss.qvalue_network_params.values(True, True))
    assert all(not torch.equal(a, b) for a, b in zip(after, before) if a.requires_grad)
    assert_policy_file_rebuilds_the_actor(u, tmp_path)


def test_a_policy_of_another_architecture_is_refused_for_fine_tuning():
    _, plain = updater("sac_cpu")
    _, ln = updater("sac_ln")
    problems = ln.init_from({"format": "drs-torchrl/policy", **plain.policy_checkpoint()})
    assert any("normalised (None, None), this run's (None, 'layer')" in p for p in problems)


def test_an_unknown_normalisation_is_a_config_error():
    from drs_torchrl.runtime.errors import ConfigError

    with pytest.raises(ConfigError, match="unknown normalisation 'batch'"):
        updater("sac_cpu", "algo.critic_norm=batch")


def test_crossq_has_no_targets_delays_the_actor_and_acts_on_running_statistics(tmp_path):
    from torchrl.modules import BatchRenorm1d

    cfg, u = updater("crossq")
    assert cfg.algo.name == "crossq" and float(cfg.algo.utd) == 1.0 and u.target_updater is None
    assert type(u.loss).__name__ == "CrossQLoss"
    brn = [m for m in u.actor.modules() if isinstance(m, BatchRenorm1d)]
    assert len(brn) == 2 and sum(isinstance(m, BatchRenorm1d) for m in u.qvalue.modules()) == 2
    actor_params = lambda: [p.detach().clone() for p in u.loss.actor_network_params.values(True, True)]  # noqa: E731
    critic_params = lambda: [p.detach().clone() for p in u.loss.qvalue_network_params.values(True, True)]  # noqa: E731
    changed = lambda a, b: any(not torch.equal(x, y) for x, y in zip(a, b))  # noqa: E731
    moved = []
    for _ in range(4):  # updates 0 and 3 train the actor (policy_delay 3); every update trains the critics
        a0, c0 = actor_params(), critic_params()
        u.step()
        moved.append((changed(a0, actor_params()), changed(c0, critic_params())))
        # acting (collection, evaluation) on running statistics
        assert not u.actor.training and not u.loss.qvalue_network.training
    assert [m[1] for m in moved] == [True] * 4
    # the actor's running statistics move on every update (the loss samples next actions with it) ...
    assert [m[0] for m in moved][1:3] == [True, True]
    # ... but its weights only on updates 0 and 3
    w = lambda: [p.detach().clone() for n, p in u.actor.named_parameters()]  # noqa: E731
    before = w()
    u.step()  # update 4: no actor step
    assert not changed(before, w())
    u.step()  # update 5: no actor step
    u.step()  # update 6: the actor steps
    assert changed(before, w())
    # the module that acts holds the running statistics the loss trains
    assert any(float(m.running_mean.abs().sum()) > 0 for m in brn)
    assert_policy_file_rebuilds_the_actor(u, tmp_path)
