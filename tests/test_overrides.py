"""apps/overrides.py: a '+key=value' that adds a key nothing reads, and a constructor argument its target does not
take, are refused with the setting meant; the free-form places and every shipped config pass."""

import os

import pytest
from hydra import compose, initialize_config_dir

from drs_torchrl.apps import cli  # noqa: F401 (registers the configs' resolvers)
from drs_torchrl.apps.maze import MazeConfigError
from drs_torchrl.apps.overrides import check_added_settings, check_constructor_arguments
from drs_torchrl.config_dir import conf_dir
from drs_torchrl.runtime.errors import ConfigError


def checked(app, *overrides, error=ConfigError):
    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        cfg = compose(app, overrides=list(overrides))
        check_added_settings(cfg, list(overrides), app, app, error)
    check_constructor_arguments(cfg, error)
    return cfg


@pytest.mark.parametrize(
    "app,overrides",
    [
        ("learn", ["+env.variant_overrides.goal_thresh=0.05"]),  # a variant parameter (the family checks its name)
        ("learn", ["env=custom", "+env.variants.wider={robot_init_qpos_noise: 0.3}"]),
        ("learn", ["+algo.compile_kwargs.mode=max-autotune"]),
        ("learn", ["+ablation=one_stage"]),  # a config group
        ("learn", ["+algo.collector.num_workers=2"]),  # an argument of AsyncCollector (through its bases' **kwargs)
        ("learn", ["++algo.gamma=0.9"]),  # ++ of a setting that exists
        ("reuse", ["reward=sparse", "+algo.loss.fixed_alpha=true"]),
        ("maze", ["++dqn.lr=1e-3"]),
    ],
)
def test_free_form_additions_and_existing_settings_pass(app, overrides):
    checked(app, *overrides)


@pytest.mark.parametrize(
    "app,overrides,message",
    [
        ("learn", ["+foo=1"], r"^\+foo: drs-learn has no setting 'foo' \('\+' adds a key that nothing reads"),
        ("learn", ["+algo.lr=1e-3"], r"no setting 'algo.lr' .*did you mean algo\.optim\.lr=\.\.\.\?$"),
        ("reuse", ["++reward.disc.windw=5"], r"^\+\+reward\.disc\.windw: .*did you mean reward\.disc\.window="),
        ("learn", ["++foo.bar=1"], r"no setting 'foo.bar'"),
        (
            "learn",
            ["+algo.loss.alpha_int=1"],
            r"^algo\.loss\.alpha_int: torchrl\.objectives\.SACLoss takes no argument 'alpha_int'; "
            r"did you mean algo\.loss\.alpha_init\?",
        ),
        ("learn", ["algo=ppo", "+algo.collector.num_threads=1"], r"torchrl\.collectors\.Collector takes no argument"),
        (
            "learn",
            ["algo.collector._target_=torchrl.collectors.AsyncColector"],
            r"cannot be imported: torchrl\.collectors has no 'AsyncColector'; did you mean "
            r"torchrl\.collectors\.AsyncCollector\?$",
        ),
        ("learn", ["algo.optim._target_=torch.optimz.Adam"], r"module 'torch\.optimz' does not import"),
        ("quickstart", ["+baseline=[dense]"], r"drs-quickstart has no setting 'baseline'.*did you mean baselines="),
    ],
)
def test_an_added_key_nothing_reads_or_an_argument_nobody_takes_is_refused(app, overrides, message):
    with pytest.raises(ConfigError, match=message):
        checked(app, *overrides)


def test_drs_maze_refuses_an_added_key_with_its_own_error():
    with pytest.raises(MazeConfigError, match=r"drs-maze has no setting 'dqn\.lr2'.*did you mean dqn\.lr="):
        checked("maze", "+dqn.lr2=1", error=MazeConfigError)


def names(group):
    return sorted(f[: -len(".yaml")] for f in os.listdir(os.path.join(conf_dir(), group)) if f.endswith(".yaml"))


@pytest.mark.parametrize(
    "app,overrides",
    [("learn", [f"algo={a}"]) for a in names("algo")]
    + [(app, [f"reward={r}"]) for r in names("reward") for app in ("learn", "reuse")]
    + [("learn", [f"env={e}"]) for e in names("env") if e != "maze"]  # (the maze: ("maze", []) below)
    + [("learn", [f"+ablation={a}"]) for a in names("ablation")]
    + [("learn", ["algo=ppo", "reward=gail"]), ("maze", []), ("maze", ["agent=ppo"]), ("quickstart", [])],
)
def test_every_shipped_config_builds_only_arguments_its_targets_take(app, overrides):
    checked(app, *overrides)
