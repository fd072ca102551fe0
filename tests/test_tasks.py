"""Task families (``drs_torchrl.tasks``) without simulating: what ``env_args`` gives and refuses."""

import re
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from drs_torchrl.runtime.errors import ConfigError, UserError
from drs_torchrl.tasks import family_from_config, get_family, list_families

CONF = Path(__file__).resolve().parents[1] / "conf"


def test_a_misspelt_variant_parameter_is_a_user_error_naming_the_known_ones(pick_cube):
    """drs-eval --override cube_half_sze=0.016 / +env.variant_overrides.cube_half_sze=...: not the env's TypeError."""
    with pytest.raises(ConfigError) as e:
        pick_cube.env_args("train", {"cube_half_sze": 0.016})
    assert isinstance(e.value, UserError)
    assert str(e.value).startswith(
        "family 'pick_cube' has no variant parameter 'cube_half_sze' (did you mean 'cube_half_size'?); its variant "
        "parameters: ['cube_half_size', 'goal_thresh', 'placed_thresh'], and PickCubeSized-v1 also takes ["
    )
    assert "'robot_init_qpos_noise'" in str(e.value) and "'sim_backend'" not in str(e.value)  # set by drs-torchrl
    with pytest.raises(ConfigError, match="'cube_half_sze'"):
        pick_cube.variant_kwargs("cube_2cm", {"cube_half_sze": 0.016})  # a single variant (drs-demos --from-h5)
    with pytest.raises(ConfigError, match="'success_retrun' \\(did you mean 'success_return'\\?\\)"):
        get_family("half_cheetah").env_args("train", {"success_retrun": 100})


def test_variant_parameters_and_env_arguments_are_accepted(pick_cube):
    args = pick_cube.env_args("train", {"cube_half_size": 0.016, "robot_init_qpos_noise": 0.1})
    assert [v["cube_half_size"] for v in args["env_kwargs"]["variants"]] == [0.016, 0.016]
    assert pick_cube.variant_kwargs("cube_2cm", {"placed_thresh": 0.05}) == {
        "cube_half_size": 0.02,
        "placed_thresh": 0.05,
    }
    custom = family_from_config(
        OmegaConf.merge(
            OmegaConf.load(CONF / "env" / "custom.yaml"),
            {"family": "poke_tasks_test", "env_id": "PokeCube-v1", "stage_keys": ["is_peg_grasped", "success"]},
        )
    )
    assert custom.env_args("train", {"robot_init_qpos_noise": 0.1})["env_kwargs"]["robot_init_qpos_noise"] == 0.1
    with pytest.raises(ConfigError, match="family 'poke_tasks_test' has no variant parameter 'robot_init_noise'"):
        custom.env_args("train", {"robot_init_noise": 0.1})


def config_examples() -> list[tuple[str, str]]:
    """(family, variant parameter) of every ``variant_overrides.KEY`` example in conf/env/ and conf/ablation/."""
    out = []
    for path in sorted((CONF / "env").glob("*.yaml")):
        family = OmegaConf.load(path).get("family") or path.stem
        out += [(family, key) for key in re.findall(r"variant_overrides\.(\w+)", path.read_text())]
    for path in sorted((CONF / "ablation").glob("*.yaml")):
        keys = OmegaConf.to_container(OmegaConf.load(path)).get("env", {}).get("variant_overrides") or {}
        out += [("pick_cube", key) for key in keys]
    return sorted(set(out))


@pytest.mark.parametrize("family, key", config_examples())
def test_the_configs_example_overrides_are_accepted_by_their_family(family, key):
    if family not in list_families():
        pytest.skip(f"{family} is defined in config")
    for split in ("train", "test"):
        get_family(family).env_args(split, {key: 1})
