"""Every learned baseline through drs-learn and drs-reuse at tiny budgets (real MuJoCo HalfCheetah, whose
one stage a tiny return threshold makes reachable), resume of a classifier run, and the demo checks."""

import json
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
import torch

from drs_torchrl.transforms import ClassifierReward, load_reward
from budgets import HALF_CHEETAH, tiny

pytestmark = [pytest.mark.sim, pytest.mark.slow]
BIN = Path(sys.executable).parent
TINY = [*HALF_CHEETAH, *tiny(frames=384, hidden=32)]


def _run(cmd, *args, cwd):
    env = dict(os.environ, PYTHONWARNINGS="ignore", OMP_NUM_THREADS="1")
    return subprocess.run(
        [str(BIN / cmd), *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=600, check=False
    )


@pytest.fixture(scope="module")
def demos(tmp_path_factory):
    """Demonstrations with actions, recorded from a (random-init) SAC policy whose episodes pass the threshold."""
    from omegaconf import OmegaConf

    from drs_torchrl.demos import record_policy_demos, save_demos
    from drs_torchrl.envs.factory import make_family_env
    from drs_torchrl.models import POLICY_FORMAT, make_sac_modules
    from drs_torchrl.tasks import get_family

    d = tmp_path_factory.mktemp("demos")
    torch.manual_seed(0)
    env = make_family_env(get_family("half_cheetah"), "train", seed=0, max_episode_steps=100)
    actor, _ = make_sac_modules(env.observation_spec, env.action_spec, ["observation", "stage_indicators"], [32, 32])
    env.close()
    (d / "run" / "checkpoints").mkdir(parents=True)
    torch.save(
        {
            "format": POLICY_FORMAT,
            "version": 1,
            "frames": 0,
            "family": "half_cheetah",
            "policy_in_keys": ["observation", "stage_indicators"],
            "hidden": [32, 32],
            "actor": actor.state_dict(),
        },
        d / "run" / "checkpoints" / "policy.pt",
    )
    OmegaConf.save(
        OmegaConf.create(
            {
                "env": {
                    "family": "half_cheetah",
                    "split": "train",
                    "max_episode_steps": 100,
                    "variant_overrides": {"success_return": 0.0},
                }
            }
        ),
        d / "run" / "config.yaml",
    )
    states, meta = record_policy_demos(
        d / "run", None, 4, seed=1, deterministic=False, max_episodes=400, progress=False
    )
    assert "action" in states.keys() and "state" in states.keys() and meta["actions"]["size"] == 6
    return save_demos(states, meta, d / "hc.demos")


@pytest.mark.parametrize(
    "method,extra",
    [
        ("vice_raq", []),
        ("oril", ["reward.random_episodes=2", "reward.offline_updates=20"]),
        ("gail", []),
    ],
)
def test_each_learned_baseline_learns_and_is_reused(tmp_path, demos, method, extra):
    learn = tmp_path / "learn"
    args = [*TINY, f"reward={method}", *extra, f"hydra.run.dir={learn}", "seed=1"]
    if method != "vice_raq":
        args.append(f"demos.path={demos}")
    p = _run("drs-learn", *args, cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    summary = json.loads((learn / "summary.json").read_text())
    assert summary["updates"] > 0
    ck = learn / "checkpoints" / "reward.pt"
    reward = load_reward(ck)
    assert isinstance(reward, ClassifierReward) and reward.method == method
    assert reward.metadata["family"] == "half_cheetah" and reward.use_action == (method == "gail")
    if method == "oril":
        assert summary["offline_updates"] == 20 and summary["classifier_negatives"] > 0
        assert bool(reward.classifier.trained)
    if method == "vice_raq":
        assert summary["classifier_positives"] + summary["classifier_negatives"] == summary["frames"]
    # reuse: the frozen classifier (gail also as gail_stages, with the semi-sparse term)
    for name in [method] + (["gail_stages"] if method == "gail" else []):
        out = tmp_path / f"reuse_{name}"
        p = _run(
            "drs-reuse",
            *TINY,
            f"reward={name}",
            f"reward.checkpoint={ck}",
            "env.split=test",
            f"hydra.run.dir={out}",
            cwd=tmp_path,
        )
        assert p.returncode == 0, p.stderr[-3000:]
        assert json.loads((out / "summary.json").read_text())["updates"] > 0


@pytest.mark.parametrize("method", ["vice_raq", "oril"])
def test_a_classifier_run_resumes_with_its_data(tmp_path, demos, method):
    run = tmp_path / method
    extra = [f"demos.path={demos}", "reward.random_episodes=2", "reward.offline_updates=5"] if method == "oril" else []
    p = _run("drs-learn", *TINY, f"reward={method}", *extra, f"hydra.run.dir={run}", cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    first = json.loads((run / "summary.json").read_text())
    state = torch.load(run / "checkpoints" / "state" / "trainer.pt", weights_only=True)
    assert state["learner"]["updates"] == first["disc_updates"]
    p = _run("drs-learn", f"resume={run}", "total_frames=512", cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    second = json.loads((run / "summary.json").read_text())
    assert second["frames"] == 512 and second["disc_updates"] >= first["disc_updates"]
    if method == "vice_raq":  # the classifier's data came back: every state of both parts is labelled
        assert second["classifier_positives"] + second["classifier_negatives"] == 512
    else:  # ORIL's offline data came back once, not twice, and it did not train again
        assert second["classifier_positives"] == first["classifier_positives"]
        assert second["classifier_negatives"] == first["classifier_negatives"] and second["disc_updates"] == 5


def test_gail_demonstrations_must_carry_the_agents_actions(tmp_path, demos):
    from drs_torchrl.demos import load_demos, save_demos

    episodes, meta = load_demos(demos)
    states_only = torch.cat(episodes).exclude("action", "state")
    meta = {k: v for k, v in meta.items() if k != "actions"}
    path = save_demos(states_only, meta, tmp_path / "states_only.demos")
    p = _run("drs-learn", *TINY, "reward=gail", f"demos.path={path}", f"hydra.run.dir={tmp_path / 'a'}", cwd=tmp_path)
    assert p.returncode != 0 and "holds states only" in p.stderr and "drs-demos --from-policy" in p.stderr
    # (state-only GAIL, reward.use_action=false, learns from such files: test_learners.py)
    p = _run("drs-learn", *TINY, "reward=oril", f"hydra.run.dir={tmp_path / 'c'}", cwd=tmp_path)
    assert p.returncode != 0 and "demos.path" in p.stderr
    shutil.rmtree(tmp_path / "c", ignore_errors=True)


def test_fine_tuning_starts_from_the_phase1_agent(tmp_path):
    """Sec. 5.4.2: init_from=RUN_DIR starts phase 2 from that run's actor, critics and entropy coefficient."""
    from omegaconf import OmegaConf

    from drs_torchrl.runtime.errors import ConfigError
    from drs_torchrl.apps.build import Run

    learn = tmp_path / "learn"
    static = [a for a in TINY if not a.startswith("reward.disc")]  # static rewards have no learner settings
    p = _run("drs-learn", *static, "reward=sparse", f"hydra.run.dir={learn}", cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    ck = torch.load(learn / "checkpoints" / "policy.pt", weights_only=True)
    cfg = OmegaConf.load(learn / "config.yaml")
    cfg.phase, cfg.env.split = "reuse", "test"
    cfg.init_from = str(learn)
    tr = Run(cfg, "reuse", tmp_path / "tuned")
    try:
        for k, v in ck["actor"].items():
            assert torch.equal(tr.actor.state_dict()[k], v), k
        q = tr.updater.loss.qvalue_network_params.data.cpu().to_dict()
        tq = tr.updater.loss.target_qvalue_network_params.data.cpu()
        from tensordict import TensorDict

        saved = TensorDict(ck["qvalue_params"])
        assert all(torch.equal(a, b) for a, b in zip(saved.values(True, True), TensorDict(q).values(True, True)))
        assert all(torch.equal(a, b) for a, b in zip(saved.values(True, True), tq.values(True, True)))
        assert torch.equal(tr.updater.loss.log_alpha.detach(), ck["log_alpha"])
    finally:
        tr.close()
    cfg.algo.hidden = [16, 16]
    with pytest.raises(ConfigError, match="hidden \\[32, 32\\].*hidden \\[16, 16\\]"):
        Run(cfg, "reuse", tmp_path / "bad")
    out = tmp_path / "cli"
    p = _run(
        "drs-reuse",
        *static,
        "reward=semi_sparse",
        f"init_from={learn}",
        "env.split=test",
        f"hydra.run.dir={out}",
        cwd=tmp_path,
    )
    assert p.returncode == 0, p.stderr[-3000:]
    assert json.loads((out / "summary.json").read_text())["init_from"] == str(learn)


def test_demonstrations_fill_a_share_of_every_sac_batch(tmp_path, demos):
    """demos.sac_share (RLPD-style, beyond the paper): a fixed share of each SAC batch comes from the
    demonstrations' transitions, rewarded by the current learned reward."""
    from hydra import compose, initialize_config_dir

    from drs_torchrl.demos import load_demos
    from drs_torchrl.apps.cli import conf_dir
    from drs_torchrl.runtime.errors import ConfigError
    from drs_torchrl.apps.build import Run

    def cfg(*extra):
        base = [a for a in TINY if not a.startswith("reward.disc")] if "reward=sparse" in extra else TINY
        with initialize_config_dir(config_dir=conf_dir(), version_base=None):
            return compose("learn", overrides=[*base, *extra])

    tr = Run(cfg(f"demos.path={demos}", "demos.sac_share=0.25"), "learn", tmp_path / "run")
    try:
        tr.run()
        with warnings.catch_warnings():  # the agent's buffer is built for its share: no batch-size warning
            warnings.simplefilter("error")
            batch = tr.updater.sample()
        assert batch.shape == (32,) and tr.updater.demo_batch == 8 and tr.updater.replay.batch_size == 24
        episodes, _ = load_demos(demos)
        demo_obs = torch.cat([ep["state", "observation"] for ep in episodes])
        from_demos = (batch["observation"][:, None, :] == demo_obs[None]).all(-1).any(-1)
        assert int(from_demos.sum()) >= 8 and bool(from_demos[-8:].all())
        # their rewards are the learned reward's, recomputed now
        assert torch.allclose(batch["next", "reward"][-8:], tr.learned.reward(batch["next"][-8:]))
    finally:
        tr.close()
    with pytest.raises(ConfigError, match="reward learned in this run"):
        Run(cfg(f"demos.path={demos}", "demos.sac_share=0.25", "reward=sparse"), "learn", tmp_path / "b")
    with pytest.raises(ConfigError, match="must be in \\[0, 1\\)"):
        Run(cfg(f"demos.path={demos}", "demos.sac_share=1.5"), "learn", tmp_path / "c")
    # actions of another controller (e.g. the planner's joint positions) are refused with the fix
    from drs_torchrl.demos import save_demos

    episodes, meta = load_demos(demos)
    wide = torch.cat(episodes)
    wide.set("action", torch.cat([wide["action"], wide["action"]], -1))
    meta = {**meta, "actions": {**meta["actions"], "size": 12}}
    wide_path = save_demos(wide, meta, tmp_path / "wide.demos")
    with pytest.raises(ConfigError, match="12-dimensional; this run acts with 6-dimensional.*drs-demos --control-mode"):
        Run(cfg(f"demos.path={wide_path}", "demos.sac_share=0.25"), "learn", tmp_path / "d")


def test_demonstrations_in_the_sac_batch_only_leave_the_stage_buffers_to_the_agent(tmp_path, demos):
    """demos.stage_buffers=false: the SAC batch still draws its share from the demonstrations, but the top
    stage buffer (the discriminators' positives) holds none of them; without a SAC share it is refused."""
    from hydra import compose, initialize_config_dir

    from drs_torchrl.apps.cli import conf_dir
    from drs_torchrl.runtime.errors import ConfigError
    from drs_torchrl.apps.build import Run

    def cfg(*extra):
        with initialize_config_dir(config_dir=conf_dir(), version_base=None):
            return compose("learn", overrides=[*TINY, f"demos.path={demos}", *extra])

    top = None
    for filed in (True, False):
        tr = Run(
            cfg("demos.sac_share=0.25", f"demos.stage_buffers={str(filed).lower()}"), "learn", tmp_path / f"run{filed}"
        )
        try:
            assert tr.updater.demo_batch == 8
            n_top = int(tr.learner.stage_buffers.stage_counts()[-1])
            if filed:
                top = n_top
                assert tr.learner.num_demos > 0 and n_top > 0
            else:
                assert tr.learner.num_demos == 0 and n_top == 0 and top > 0
        finally:
            tr.close()
    with pytest.raises(ConfigError, match="would not be used at all; set demos.sac_share=0.25"):
        Run(cfg("demos.sac_share=0", "demos.stage_buffers=false"), "learn", tmp_path / "none")
    with pytest.raises(ConfigError, match="demos.stage_buffers=false is for drs-learn reward=drs"):
        Run(cfg("demos.sac_share=0.25", "demos.stage_buffers=false", "reward=vice_raq"), "learn", tmp_path / "vice")


def test_the_recipe_default_keeps_drs_demonstrations_in_the_sac_batch_only(tmp_path, demos):
    """demos.stage_buffers=auto (the default recipe, docs/recipe.md): reward=drs with demonstrations that carry
    the agent's actions -> the SAC batch only (resolved false and saved so); with sac_share=0, or for a
    learned baseline, they go into the stage buffers / the learner as before (resolved true)."""
    from hydra import compose, initialize_config_dir

    from drs_torchrl.apps.cli import conf_dir
    from drs_torchrl.apps.build import Run

    def cfg(*extra):
        with initialize_config_dir(config_dir=conf_dir(), version_base=None):
            return compose("learn", overrides=[*TINY, f"demos.path={demos}", *extra])

    assert cfg().demos.stage_buffers == "auto" and cfg().stop_at_success == 0.8
    for extra, sac_only in (((), True), (("demos.sac_share=0",), False), (("reward=vice_raq",), False)):
        tr = Run(cfg(*extra), "learn", tmp_path / f"run{len(extra)}{extra[:1]}")
        try:
            assert tr.setting("demos.stage_buffers") is (not sac_only), extra
            if tr.cfg.reward.name == "drs":
                assert (int(tr.learner.stage_buffers.stage_counts()[-1]) == 0) is sac_only, extra
        finally:
            tr.close()


def test_sac_share_auto_shares_where_the_demonstrations_allow_and_says_why_not(tmp_path, demos, capsys):
    """demos.sac_share=auto (the default): AUTO_SAC_SHARE of each SAC batch where the demonstrations carry
    the agent's actions, 0 (with the reason on the console) where they do not; the choice is saved resolved."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from drs_torchrl.demos import load_demos, save_demos
    from drs_torchrl.apps.cli import conf_dir
    from drs_torchrl.data.demo_mix import AUTO_SAC_SHARE
    from drs_torchrl.apps.build import Run

    def trainer(name, *extra):
        with initialize_config_dir(config_dir=conf_dir(), version_base=None):
            cfg = compose("learn", overrides=[*TINY, *extra])
        assert cfg.demos.sac_share == "auto"
        return Run(cfg, "learn", tmp_path / name)

    tr = trainer("a", f"demos.path={demos}")
    try:
        assert tr.updater.demo_batch == round(AUTO_SAC_SHARE * 32) and tr.setting("demos.sac_share") == AUTO_SAC_SHARE
        # recorded once, in config.yaml; the composed config is not written to
        assert OmegaConf.load(tmp_path / "a" / "config.yaml").demos.sac_share == AUTO_SAC_SHARE
        assert tr.cfg.demos.sac_share == "auto"
        assert "demos.sac_share=auto -> 0.25: a share of every SAC batch" in capsys.readouterr().out
    finally:
        tr.close()
    episodes, meta = load_demos(demos)
    wide = torch.cat(episodes)
    wide.set("action", torch.cat([wide["action"], wide["action"]], -1))
    wide_path = save_demos(wide, {**meta, "actions": {**meta["actions"], "size": 12}}, tmp_path / "wide.demos")
    for name, extra in (
        ("b", [f"demos.path={wide_path}"]),
        ("c", []),
    ):  # another controller's actions; no demonstrations
        tr = trainer(name, *extra)
        try:
            assert tr.updater.demo_replay is None and tr.updater.demo_batch == 0 and tr.setting("demos.sac_share") == 0
        finally:
            tr.close()
    out = capsys.readouterr().out
    assert "demos.sac_share=auto -> 0: demos.sac_share: the actions in" in out and "12-dimensional" in out
    assert out.count("demos.sac_share=auto") == 1  # a run without demonstrations has nothing to say


@pytest.mark.parametrize("use_action", [False, True])
def test_a_classifier_reward_in_an_env_passes_torchrl_spec_checks(use_action):
    from torchrl.envs.utils import check_env_specs

    from drs_torchrl.envs.factory import make_family_env
    from drs_torchrl.tasks import get_family

    env = make_family_env(get_family("half_cheetah"), "train", seed=0, max_episode_steps=20)
    try:
        r = ClassifierReward(
            ["observation", "stage_indicators"],
            {"observation": 17, "stage_indicators": 1},
            1,
            use_action=use_action,
            action_dim=6 if use_action else None,
            stage_weight=0.5,
        )
        env.append_transform(r)
        check_env_specs(env)
        td = env.rollout(5)
        lo, hi = r.reward_bounds()
        assert (
            env.reward_spec.space.low.item() == pytest.approx(lo)
            and ((td["next", "reward"] >= lo) & (td["next", "reward"] <= hi)).all()
        )
    finally:
        env.close()
