"""apps/schema.py: the types and ranges of drs-learn / drs-reuse / drs-maze settings, declared once as structured
configs and checked with OmegaConf's validation, for composed and for resumed configs alike."""

import dataclasses

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.config_store import ConfigStore
from omegaconf import OmegaConf

from drs_torchrl.apps.maze import MazeConfigError, validate
from drs_torchrl.apps.schema import MazeSchema, RunSchema, check, setting
from drs_torchrl.apps.validation import validate_config
from drs_torchrl.config_dir import conf_dir
from drs_torchrl.runtime.errors import ConfigError


def composed(name, *overrides):
    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        return compose(name, overrides=list(overrides))


@pytest.mark.parametrize(
    "config,overrides",
    [
        ("learn", []),
        ("learn", ["algo=ppo"]),
        ("learn", ["algo=sac_paper", "env=turn_valve"]),
        ("learn", ["reward=vice_raq"]),
        ("reuse", ["reward=sparse"]),
        ("reuse", ["reward=gail_stages"]),
        ("maze", []),
        ("maze", ["agent=ppo", "phase=reuse", "reward.name=sparse"]),
    ],
)
def test_every_shipped_config_passes_its_schema(config, overrides):
    check(composed(config, *overrides), MazeSchema if config == "maze" else RunSchema)


@pytest.mark.parametrize(
    "override,message",
    [
        ("total_frames=abc", "total_frames must be an integer, got 'abc' (str); e.g. total_frames=200000"),
        ("seed=1.5", "seed must be an integer, got 1.5 (float)"),
        ("total_frames=true", "total_frames must be an integer, got True (bool)"),
        ("algo.gamma=high", "algo.gamma must be a number, got 'high' (str); e.g. algo.gamma=0.8"),
        ("reward.disc.lr=[1]", "reward.disc.lr must be a number, got [1] (list)"),
        ("eval.episode_seed=first", "eval.episode_seed must be an integer or null, got 'first'"),
        ("total_frames=-5", "total_frames must be > 0, got -5; e.g. total_frames=200000"),
        ("seed=-1", "seed must be >= 0, got -1 (it seeds numpy, torch and the simulator)"),  # numpy refuses it later
        ("algo.gamma=0", "algo.gamma must be in (0, 1], got 0"),
        ("eval.episode_seed=-1", "eval.episode_seed must be null or >= 0, got -1"),
        ("stop_at_success=1.5", "stop_at_success must be null or a success rate in [0, 1], got 1.5"),
        ("algo.reward_updates_per_update=0", "reward_updates_per_update must be > 0, got 0 (fractions allowed"),
        ("demos.num=-1", "demos.num must be null or > 0, got -1 (null: all in the file)"),
        ("algo.buffer_size=16", "algo.buffer_size (16) is smaller than algo.batch_size (256)"),  # cross-field
        # a switch is true or false: bool("no") is True, so "no" would have turned it on
        ("overwrite=no", "overwrite must be true or false, got 'no' (str); e.g. overwrite=true"),
        ("algo.compile=off", "algo.compile must be false, true (= loss), loss or update, got 'off'"),
        ("logger.tensorboard=0", "logger.tensorboard must be true or false, got 0 (int)"),
        ("reward.disc.latch=yes", "reward.disc.latch must be true or false, got 'yes'"),
        ("algo.optim.lr=-1", "algo.optim.lr must be > 0, got -1"),
        ("reward.formula=resacled", "reward.formula must be one of paper, rescaled, sum, got 'resacled'"),
        ("reward.activation=gelu", "reward.activation must be one of sigmoid, relu, tanh, elu, got 'gelu'"),
        ("env.num_envs=0", "env.num_envs must be > 0, got 0"),
        ("env.max_episode_steps=0", "env.max_episode_steps must be null or > 0, got 0 (null: the family's)"),
        ("env.cpu_batching=threads", "env.cpu_batching must be one of serial, parallel, got 'threads'"),
        # a section given one value, and the networks' widths: each had been an internal error (StopIteration,
        # TypeError deep in torch) instead of a setting named
        (
            "eval=5",
            "eval is a section of settings, not one value (got 5); set one of its settings, e.g. eval.interval=",
        ),
        ("reward.disc=3", "reward.disc is a section of settings, not one value (got 3)"),
        ("demos=null", "demos is a section of settings, not one value (got null)"),
        ("algo.hidden=[abc,16]", "algo.hidden[0] must be an integer, got 'abc' (str); e.g. algo.hidden=[256,256,256]"),
        ("algo.hidden=64", "algo.hidden must be a list of integers, got 64 (int)"),
        ("algo.hidden=[0,16]", "algo.hidden must be layer widths, each > 0, got [0, 16]"),
        ("reward.hidden=[-1]", "reward.hidden must be layer widths, each > 0, got [-1]; e.g. reward.hidden=[32]"),
        # settings of demonstrations with none given: they had done nothing, silently
        ("demos.num=5", "demos.num=5 is a setting of the demonstrations in demos.path, which is not set"),
        ("demos.stage_buffers=true", "demos.stage_buffers=true is a setting of the demonstrations in demos.path"),
    ],
)
def test_a_bad_value_is_named_with_its_type_or_range_and_an_example(override, message):
    with pytest.raises(ConfigError) as err:
        validate_config(composed("learn", override), "learn")
    assert message in str(err.value) and "\n" not in str(err.value)


def test_a_resumed_config_is_checked_like_a_composed_one(tmp_path):
    """A run's config.yaml edited by hand never passes Hydra's composition: the same check refuses it."""
    cfg = composed("learn")
    path = tmp_path / "config.yaml"
    path.write_text(OmegaConf.to_yaml(cfg, resolve=False).replace("total_frames: 300000", "total_frames: lots"))
    with pytest.raises(ConfigError, match="total_frames must be an integer, got 'lots'"):
        validate_config(OmegaConf.load(path), "learn")


def test_a_resumed_run_keeps_the_stage_buffers_choice_auto_saved():
    """A run saves what demos.stage_buffers=auto chose (true, with or without demonstrations): its resume passes."""
    cfg = composed("learn")
    cfg.demos.stage_buffers = True
    with pytest.raises(ConfigError, match="demos.stage_buffers=true is a setting of the demonstrations"):
        validate_config(cfg, "learn")
    cfg.resume = "runs/learn/x"
    validate_config(cfg, "learn")


def test_an_on_policy_algorithm_takes_no_random_warm_up():
    """PPO's loss reads the log-probabilities of the policy that collected; random warm-up actions have none."""
    with pytest.raises(ConfigError, match=r"algo.learning_starts must be 0 for algo=ppo .*got 1000"):
        validate_config(composed("learn", "algo=ppo", "algo.learning_starts=1000"), "learn")
    validate_config(composed("learn", "algo=sac_cpu", "algo.learning_starts=1000"), "learn")


def test_the_mazes_agents_are_the_algo_nodes_and_dqn_is_refused_on_continuous_actions():
    """conf/algo/dqn.yaml and ppo.yaml are the maze's `dqn` and `ppo` nodes (relative links resolve there); drs-learn
    refuses DQN elsewhere."""
    maze = composed("maze", "dqn.lr=0.0005", "dqn.gamma=0.9")
    assert maze.dqn.name == "dqn" and maze.dqn.updater.optim.lr == 0.0005 and maze.dqn.updater.gamma == 0.9
    assert maze.dqn.updater.target_update.value_network_update_interval == 100
    # conf/algo/ppo.yaml at ppo, the maze's values on top; the same file as drs-learn's algo=ppo
    maze = composed("maze", "agent=ppo", "ppo.lr=0.002")
    assert maze.ppo.updater.gamma == 0.99 and maze.ppo.updater.optim.lr == 0.002 and maze.ppo.updater.hidden == [64, 64]
    assert maze.ppo.updater.policy_in_keys == ["observation"] and maze.ppo.updater.entropy_coeff == 0.01
    learn = composed("learn", "algo=ppo", "algo.lr=0.002")
    assert (
        learn.algo.updater.gamma == 0.8
        and learn.algo.updater.optim.lr == 0.002
        and learn.algo.collector.frames_per_batch == 1000
    )
    with pytest.raises(MazeConfigError, match="the maze's PPO runs in fp32"):
        validate(composed("maze", "agent=ppo", "ppo.precision=bf16"))
    with pytest.raises(ConfigError, match=r"^algo=dqn acts on discrete actions: it runs the maze .*algo=sac_cpu"):
        validate_config(composed("learn", "algo=dqn"), "learn")
    # conf/env/maze.yaml composed into drs-learn's config (a study's check, a multirun): refused, naming drs-maze
    with pytest.raises(ConfigError, match=r"^env=maze is run by drs-maze .* run drs-maze phase=learn\|reuse"):
        validate_config(composed("learn", "env=maze", "algo=dqn"), "learn")


def test_settings_an_algorithm_does_not_have_are_not_demanded():
    cfg = composed("learn", "algo=ppo")
    assert "utd" not in cfg.algo and "tau" not in cfg.algo
    validate_config(cfg, "learn")
    assert "epochs" not in composed("learn").algo


@pytest.mark.parametrize(
    "override,message",
    [
        ("total_frames=x", "total_frames must be an integer, got 'x'"),
        ("dqn.n_steps=0", "dqn.n_steps must be >= 1, got 0"),
        ("dqn.reward_scale=0", "dqn.reward_scale must be > 0, got 0 (it multiplies the reward the agent trains on)"),
        ("reward.reuse_alpha=0.5", "reward.reuse_alpha must be null or in [0, 0.5), got 0.5"),
        ("demos=-1", "demos must be >= 0, got -1"),
        ("overwrite=no", "overwrite must be true or false, got 'no'"),
        ("num_envs=7", "frames_per_batch (256) must be a multiple of num_envs (7)"),  # cross-field, in validate
        ("eval=5", "eval is a section of settings, not one value (got 5)"),
        ("dqn.hidden=[0]", "dqn.hidden must be layer widths, each > 0, got [0]"),
        ("reward.hidden=[a]", "reward.hidden[0] must be an integer, got 'a' (str)"),
    ],
)
def test_the_maze_config_uses_the_same_schema_check(override, message):
    with pytest.raises(MazeConfigError) as err:
        validate(composed("maze", override))
    assert message in str(err.value)


def test_the_schemas_are_in_hydras_config_store_and_every_setting_has_an_example():
    repo = ConfigStore.instance().repo["schema"]
    assert {"run.yaml", "maze.yaml"} <= set(repo)

    def leaves(cls):
        for f in dataclasses.fields(cls):
            sub = next((t for t in (f.type, *getattr(f.type, "__args__", ())) if dataclasses.is_dataclass(t)), None)
            yield from leaves(sub) if sub else [f]

    for schema in (RunSchema, MazeSchema):
        for f in leaves(schema):
            assert f.name == "name" or f.metadata["example"] is not None, f.name


def test_a_new_setting_is_one_line_of_a_dataclass():
    @dataclasses.dataclass
    class Tiny:
        rate: float = setting(gt=0, lt=1, example=0.5)

    check(OmegaConf.create({"rate": 0.2, "other": "x"}), Tiny)
    with pytest.raises(ConfigError, match=r"rate must be in \(0, 1\), got 1; e.g. rate=0.5"):
        check(OmegaConf.create({"rate": 1}), Tiny)
    with pytest.raises(ValueError, match="rate must be a number"):
        check(OmegaConf.create({"rate": "fast"}), Tiny, ValueError)


@pytest.mark.parametrize("cuda", [False, True])
def test_device_cuda_is_refused_exactly_where_cuda_is_missing(monkeypatch, cuda):
    """The check itself, on a machine with or without CUDA (``torch.cuda.is_available`` set either way); the console
    script's line for the refusal: results/bad_inputs/ (run with no CUDA device visible)."""
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: cuda)
    for device in ("cuda", "cuda:1"):
        cfg = composed("learn", f"device={device}")
        if cuda:
            validate_config(cfg, "learn")  # a GPU learner is a setting like any other
        else:
            with pytest.raises(ConfigError) as err:
                validate_config(cfg, "learn")
            assert str(err.value) == f"device={device} was requested but CUDA is not available; use device=cpu"
    with pytest.raises(ConfigError, match="device must be cpu, cuda\\[:i\\] or auto, got gpu"):
        validate_config(composed("learn", "device=gpu"), "learn")
    validate_config(composed("learn", "device=auto"), "learn")
