"""A task family defined entirely in config (env=custom): built, checked against the env, learned and reused."""

import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from drs_torchrl.tasks import family_from_config, get_family
from drs_torchrl.transforms import DrSReward
from budgets import tiny

BIN = Path(sys.executable).parent
POKE = ["env=custom", "env.family=poke_cube_test", "env.env_id=PokeCube-v1", "env.stage_keys=[is_peg_grasped,success]"]
TINY = tiny()


def env_cfg(**over):
    base = OmegaConf.load(Path(__file__).parents[1] / "conf" / "env" / "custom.yaml")
    return OmegaConf.merge(base, over)


def test_config_family_has_its_stages_split_and_registers():
    fam = family_from_config(env_cfg(family="poke_two", env_id="PokeCube-v1", stage_keys=["is_peg_grasped", "success"]))
    assert fam.num_stages == 2 and fam.stage_keys == ("is_peg_grasped", "success")
    assert fam.split_variants("train") == ("default",) and fam.split_variants("test") == ("wide_start",)
    assert fam.variant_kwargs("test") == {"robot_init_qpos_noise": 0.2}
    assert get_family("poke_two") is fam
    assert family_from_config(OmegaConf.create({"family": "pick_cube"})) is get_family("pick_cube")


def test_config_family_errors_name_the_fix():
    with pytest.raises(ValueError, match="built-in family.*another name"):
        family_from_config(env_cfg(family="pick_cube"))
    with pytest.raises(ValueError, match="overlap.*env.stage_keys"):
        family_from_config(env_cfg(family="bad_split", train_variants=["default"], test_variants=["default"]))
    with pytest.raises(ValueError, match="last stage indicator must be.*'success'.*env.stage_keys"):
        family_from_config(env_cfg(family="no_success", stage_keys=["is_peg_grasped", "is_done"]))
    with pytest.raises(KeyError, match="no test variants"):
        family_from_config(env_cfg(family="no_test", test_variants=[])).split_variants("test")


@pytest.mark.parametrize(
    "over,message",
    [  # one value where a list or a mapping belongs: a string had been read letter by letter, a number had crashed
        ({"stage_keys": "success"}, "env.stage_keys must be a list, e.g. env.stage_keys=[success], got 'success'"),
        ({"train_variants": "default"}, "env.train_variants must be a list, e.g. env.train_variants=[default]"),
        ({"variants": 5}, "env.variants must map each variant's name to its parameters"),
        ({"variants": {"big": 3}}, "env.variants.big must be a mapping of the env's parameters"),
    ],
)
def test_config_family_refuses_one_value_where_a_list_or_mapping_belongs(over, message):
    with pytest.raises(ValueError) as e:
        family_from_config(OmegaConf.merge(env_cfg(family="one_value"), over))
    assert message in str(e.value)


def test_a_stage_ablation_given_one_stage_as_a_string_is_refused():
    from drs_torchrl.tasks import with_stages

    with pytest.raises(ValueError, match=r"env.stages must be a list, e.g. env.stages=\[success\], got 'success'"):
        with_stages(get_family("pick_cube"), "success")


def run(cmd, *args, cwd):
    return subprocess.run([str(BIN / cmd), *args], cwd=cwd, capture_output=True, text=True, timeout=600)


@pytest.mark.sim
@pytest.mark.slow
def test_a_stage_key_the_env_does_not_report_is_named(tmp_path, cli):
    """(In this process; the console script's one line for such a family: results/bad_inputs/.)"""
    code, err = cli("learn", *POKE[:3], "env.stage_keys=[is_grasped,success]", *TINY, f"hydra.run.dir={tmp_path / 'r'}")
    assert code == 2
    assert "does not report info entries ['is_grasped']" in err and "is_peg_grasped" in err
    assert "Traceback" not in err


@pytest.mark.sim
@pytest.mark.slow
def test_config_family_learns_a_reward_and_reuses_it_on_its_test_variant(tmp_path):
    learn = tmp_path / "learn"
    p = run("drs-learn", *POKE, *TINY, f"hydra.run.dir={learn}", cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    reward = DrSReward.from_checkpoint(learn / "checkpoints" / "reward.pt")
    assert reward.num_stages == 2 and reward.metadata["family"] == "poke_cube_test"
    assert reward.metadata["env_id"] == "PokeCube-v1"
    p = run(
        "drs-reuse",
        *POKE,
        *TINY,
        "env.split=test",
        "reward=drs",
        f"reward.checkpoint={learn / 'checkpoints' / 'reward.pt'}",
        f"hydra.run.dir={tmp_path / 'reuse'}",
        cwd=tmp_path,
    )
    assert p.returncode == 0, p.stderr[-3000:]
    assert (tmp_path / "reuse" / "checkpoints" / "policy.pt").is_file()
