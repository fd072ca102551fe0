"""The one reward registry: conf/reward/<name>.yaml names what builds each reward (slot, learner) by _target_, and a
new reward is one YAML away (no module lists reward names)."""

import re
import shutil
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import get_method
from omegaconf import OmegaConf

from drs_torchrl.config_dir import conf_dir
from drs_torchrl.learners.base import plain_step
from drs_torchrl.apps.reward_registry import available_rewards, registry_entry, with_builders
from drs_torchrl.rewards import is_learned, new_reward_learner, reused_method, reward_entry, reward_setup
from drs_torchrl.tasks import family_from_config
from drs_torchrl.apps.factories import make_envs

ROOT = Path(__file__).resolve().parents[1]


def test_every_reward_file_names_its_builders():
    names = available_rewards()
    assert names == sorted(p.stem for p in (ROOT / "conf" / "reward").glob("*.yaml"))
    assert {"drs", "sparse", "semi_sparse", "dense", "vice_raq", "oril", "gail", "gail_stages"} <= set(names)
    for name in names:
        entry = registry_entry(name)
        assert callable(get_method(entry.slot._target_)), name
        if entry.get("learner") is not None:
            assert callable(get_method(entry.learner._target_)), name
    learned = {n for n in names if is_learned(registry_entry(n))}
    assert learned == {"drs", "vice_raq", "oril", "gail", "gail_stages"}
    assert reused_method(registry_entry("gail_stages")) == "gail"


def test_an_unknown_reward_names_the_registry():
    with pytest.raises(ValueError, match=r"unknown reward 'nonsense'.*'drs'.*conf/reward"):
        registry_entry("nonsense")


def test_the_library_builds_from_the_node_it_is_given_and_a_saved_one_gets_its_builders_from_the_registry():
    """No module below the apps reads conf/: a reward node without builders (a config saved before the registry
    named them) is refused by the library, and the apps fill it in from conf/reward/ (resume, drs-eval)."""
    old = OmegaConf.create({"name": "gail_stages", "checkpoint": None, "stage_weight": 1.0})
    with pytest.raises(ValueError, match="names no builder"):
        reward_entry(old)
    filled = with_builders(old)
    assert filled is old and filled.slot == registry_entry("gail_stages").slot and reused_method(filled) == "gail"
    assert filled.stage_weight == 1.0 and filled.get("classifier_weight") is None  # its own settings are untouched
    node = registry_entry("drs")
    node.slot = {"_target_": "mine.slot"}
    assert with_builders(node).slot._target_ == "mine.slot"  # a node naming its builder keeps it


@pytest.mark.parametrize("name", ["sparse", "semi_sparse", "dense"])
def test_a_static_reward_refuses_a_checkpoint_it_would_ignore(name):
    """drs-reuse reward=dense reward.checkpoint=...: the user meant to reuse a learned reward and would get dense."""
    cfg = registry_entry(name)
    reward_setup(cfg, "reuse")  # without one: fine
    cfg.checkpoint = "runs/learn/x/checkpoints/reward.pt"
    with pytest.raises(ValueError, match=f"reward={name} is a static reward and reads no checkpoint"):
        reward_setup(cfg, "reuse")


def documented_reward_file() -> str:
    """The example file of docs/rewards.md ("Adding a reward"), as a user would copy it."""
    text = (ROOT / "docs" / "rewards.md").read_text()
    blocks = [b for b in re.findall(r"^```yaml\n(.*?)^```", text, re.S | re.M) if "conf/reward/my_classifier" in b]
    assert len(blocks) == 1, "docs/rewards.md should show one example reward file, conf/reward/my_classifier.yaml"
    return blocks[0]


@pytest.mark.sim
def test_a_new_reward_is_one_yaml_file(tmp_path, monkeypatch):
    """A copy of the configs with two new reward files, and nothing else changed: a static one (the stage index under
    another name) and a learned one (docs/rewards.md's example: VICE-RAQ's learner under another name) are composed,
    set up and learned."""
    conf = tmp_path / "conf"
    shutil.copytree(conf_dir(), conf)
    (conf / "reward" / "stage_index.yaml").write_text(
        "name: stage_index\ncheckpoint: null\noffset: null\n"
        "slot: {_target_: drs_torchrl.rewards.semi_sparse_reward, _partial_: true}\n"
    )
    (conf / "reward" / "success_classifier.yaml").write_text(
        documented_reward_file().replace("my_classifier", "success_classifier")
    )
    monkeypatch.setenv("DRS_CONF_DIR", str(conf))
    assert {"stage_index", "success_classifier"} <= set(available_rewards())
    with initialize_config_dir(config_dir=str(conf), version_base=None):
        static = compose("reuse", overrides=["env=turn_valve", "reward=stage_index"])
        learned = compose("learn", overrides=["env=turn_valve", "reward=success_classifier", "demos.path=null"])
    setup = reward_setup(static.reward, "reuse")
    assert setup.semi_sparse and setup.frozen is None and not is_learned(static.reward)
    assert is_learned(learned.reward) and reward_setup(learned.reward, "learn").learned is None
    family = family_from_config(learned.env)
    env, eval_env, _ = make_envs(
        learned.env, family, reward_setup(learned.reward, "learn"), torch.device("cpu"), seed=learned.seed
    )
    try:
        learner = new_reward_learner(
            learned.reward, family, env, {"family": family.name}, device="cpu", autocast=None, step_fn=plain_step
        )
        assert type(learner).__name__ == "SuccessClassifierLearner"
        assert learner.reward.method == "success_classifier"  # its reward.pt says which reward reuses it
    finally:
        env.close()
        eval_env.close()


def test_a_reused_drs_reward_is_used_as_it_was_learned(tmp_path):
    """drs-reuse takes Eq. 4's formula, alpha, offset, inputs and networks from the checkpoint: an override that
    says otherwise is refused, and a config that differs without one is made to say what the run uses."""
    from drs_torchrl.apps.cli import check_reused_reward_overrides
    from drs_torchrl.runtime.errors import ConfigError
    from drs_torchrl.rewards import reused_reward_settings
    from drs_torchrl.transforms import DrSReward

    path = tmp_path / "reward.pt"
    DrSReward(3, ["observation"], {"observation": 4}, formula="paper", alpha=0.25, hidden=[8]).save(path)

    def reuse(*overrides):
        with initialize_config_dir(config_dir=conf_dir(), version_base=None):
            return compose("reuse", overrides=["reward=drs", f"reward.checkpoint={path}", *overrides])

    same = ["reward.alpha=0.25", "reward.formula=paper", "reward.hidden=[8]"]
    check_reused_reward_overrides(reuse(*same), "reuse", same)  # what it was learned with: fine
    for given, learned in (("reward.alpha=0.4", "alpha=0.25"), ("reward.hidden=[64]", r"hidden=\[8\]")):
        with pytest.raises(
            ConfigError, match=rf"{re.escape(given)} is not what .*reward.pt was learned with \({learned}\)"
        ):
            check_reused_reward_overrides(reuse(given), "reuse", [given])
    cfg = reuse()  # the defaults (rescaled, alpha 1/3, hidden [32]) were not asked for: the checkpoint's are taken
    settings, notes = reused_reward_settings(cfg.reward, DrSReward.from_checkpoint(path))
    assert settings["formula"] == "paper" and settings["alpha"] == 0.25 and list(settings["hidden"]) == [8]
    assert (
        list(settings["in_keys"]) == ["observation"] and cfg.reward.formula == "rescaled"
    )  # the config is not written
    assert "reward.formula=rescaled is not used: the reused reward was learned with formula=paper" in notes
    assert not any("in_keys" in n for n in notes)  # null: the family's inputs, nothing was said otherwise


def test_a_learned_reward_is_built_from_its_entry_with_the_settings_linked_and_a_saved_one_resumes(tmp_path):
    """model + learner in the YAML build the learner; their settings link to the reward's keys (an override of
    reward.disc.lr reaches the optimiser); config.yaml keeps them as links; a reward node saved by 0.1.x (learner: a
    drs_torchrl.rewards.*_learner function, no model) gets the registry's model and learner and builds the same."""
    from torchrl.data import Composite, Unbounded

    from drs_torchrl.apps.build import save_config
    from drs_torchrl.learners import DrSLearner
    from drs_torchrl.tasks import get_family

    class _Env:  # what the builders read of an env: its specs
        observation_spec = Composite(observation=Unbounded(shape=(5,)), stage_indicators=Unbounded(shape=(2,)))

    fam = get_family("turn_valve")  # (its stage count and reward inputs; no env is made)
    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        cfg = compose("learn", overrides=["env=turn_valve", "reward=drs", "reward.disc.lr=0.001", "reward.hidden=[8]"])

    def build(node):
        return new_reward_learner(node, fam, _Env(), {"family": "synthetic"}, device="cpu", autocast=None,
                                  step_fn=plain_step)  # fmt: skip

    learner = build(cfg.reward)
    assert isinstance(learner, DrSLearner) and learner.optim.param_groups[0]["lr"] == 0.001
    assert learner.reward.discriminators.hidden == [8] and learner.reward.reward_in_keys == list(fam.reward_in_keys)
    save_config(cfg, tmp_path / "config.yaml")
    saved = OmegaConf.load(tmp_path / "config.yaml")
    assert OmegaConf.to_container(saved.reward.learner)["lr"] == "${..disc.lr}" and saved.reward.learner.lr == 0.001
    assert OmegaConf.to_container(saved.reward.model)["hidden"] == "${..hidden}"
    old = OmegaConf.create(OmegaConf.to_container(saved.reward, resolve=True))
    old.learner = {"_target_": "drs_torchrl.rewards.drs_learner", "_partial_": True}
    del old["model"]
    with_builders(old)
    assert old.learner._target_ == "drs_torchrl.learners.DrSLearner" and old.model is not None
    again = build(old)
    assert again.optim.param_groups[0]["lr"] == 0.001 and again.reward.discriminators.hidden == [8]


def test_what_the_run_asks_of_a_reward_entry_and_the_edges_of_the_saved_form():
    """Whether demonstrations live in the learner's saved stage buffers is the learner's to say (DrS), not a name's; a
    classifier's offset null is 0, as before the registry named its model; a stale saved reward of the user's own
    (a name conf/reward/ does not hold) is left as it is, so drs-eval still reads its run."""
    from torchrl.data import Bounded, Composite, Unbounded

    from drs_torchrl.rewards import stage_buffers_hold_demos
    from drs_torchrl.transforms import ClassifierReward

    assert stage_buffers_hold_demos(registry_entry("drs"))
    assert not any(stage_buffers_hold_demos(registry_entry(n)) for n in ("gail", "vice_raq", "oril", "sparse"))

    class _Env:
        observation_spec = Composite(observation=Unbounded(shape=(4,)))
        action_spec = Bounded(-1, 1, shape=(2,))

    assert ClassifierReward.from_env(_Env(), 2, ["observation"], offset=None).offset == 0.0
    mine = OmegaConf.create({"name": "my_own", "slot": {"_target_": "x.y"}, "learner": {"_target_": "x.z"}})
    assert with_builders(mine) is mine and mine.get("model") is None
