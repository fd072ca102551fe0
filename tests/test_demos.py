"""Demonstrations: recorded with ManiSkill's motion planner, saved, loaded, checked against the task."""

import json

import pytest
import torch
from tensordict import TensorDict

from drs_torchrl.data import StageBuffers
from drs_torchrl.demos import DemoError, check_demos, load_demos, record_demos, save_demos
from budgets import tiny


@pytest.fixture(scope="module")
def demo_dir(tmp_path_factory, pick_cube):
    states, meta = record_demos(pick_cube, "cube_2cm", 3, seed=10, progress=False)
    return save_demos(states, meta, tmp_path_factory.mktemp("demos") / "pc.demos")


@pytest.mark.sim
def test_recorded_demos_succeed_and_round_trip(demo_dir, pick_cube):
    episodes, meta = load_demos(demo_dir)
    assert len(episodes) == meta["episodes"] == 3
    assert meta["shapes"] == {"observation": 42, "stage_indicators": 3}
    for ep, n in zip(episodes, meta["lengths"]):
        assert ep.shape[0] == n
        assert bool(ep["success"][-1]) and not bool(ep["success"][:-1].any())  # cut at first success
        assert int(ep["stage"][-1]) == 3
        assert ep["step"].tolist() == list(range(n))
    check_demos(meta, pick_cube, {"observation": 42, "stage_indicators": 3})
    sb = StageBuffers(3, ["observation", "stage_indicators"], capacity=1000)
    for ep in episodes:
        assert sb.add_trajectory(TensorDict({"next": ep}, ep.shape), demo=True) == 3
    assert sb.stage_counts().tolist() == [0, 0, 0, sum(meta["lengths"])]


@pytest.mark.sim
def test_mismatching_demos_are_named(demo_dir, pick_cube):
    _, meta = load_demos(demo_dir)
    with pytest.raises(DemoError) as e:
        check_demos({**meta, "family": "stack_cube"}, pick_cube, {"observation": 48, "stage_indicators": 3})
    assert "'stack_cube'" in str(e.value) and "size 42" in str(e.value) and "size 48" in str(e.value)
    with pytest.raises(DemoError, match="stage indicators"):
        check_demos({**meta, "stage_keys": ["success"]}, pick_cube, {"observation": 42})


def test_bad_demo_directories(tmp_path):
    with pytest.raises(DemoError, match="no meta.json"):
        load_demos(tmp_path)
    states = TensorDict({"observation": torch.zeros(2, 3), "episode": torch.zeros(2, dtype=torch.long)}, [2])
    meta = {"format": "drs-torchrl/demos", "version": 99}
    save_demos(states, meta, tmp_path / "future.demos")
    with pytest.raises(DemoError, match="newer"):
        load_demos(tmp_path / "future.demos")
    save_demos(states, {**meta, "version": 1}, tmp_path / "broken.demos")
    for f in (tmp_path / "broken.demos" / "states").rglob("*.memmap"):
        f.write_bytes(b"")
    with pytest.raises(DemoError, match="cannot be read"):
        load_demos(tmp_path / "broken.demos")
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "meta.json").write_text(json.dumps({"format": "something-else"}))
    with pytest.raises(DemoError, match="unknown format"):
        load_demos(tmp_path / "other")
    (tmp_path / "other" / "meta.json").write_text("[]")
    with pytest.raises(DemoError, match="unknown format 'a JSON list'"):
        load_demos(tmp_path / "other")
    (tmp_path / "pick.h5").write_bytes(b"\x89HDF")  # ManiSkill's trajectory file passed as demos.path
    with pytest.raises(DemoError, match="is a ManiSkill trajectory file, not drs-torchrl demonstrations; convert it"):
        load_demos(tmp_path / "pick.h5")


def fake_demos(*seeds):
    """Tiny demonstrations of one state per seed (what save/load need; no simulation)."""
    n = len(seeds)
    states = TensorDict({"observation": torch.zeros(n, 3), "episode": torch.arange(n)}, [n])
    meta = {"format": "drs-torchrl/demos", "version": 1, "family": "pick_cube", "variant": "cube_2cm"}
    return states, {**meta, "stage_keys": [], "shapes": {}, "episodes": n, "lengths": [1] * n, "seeds": list(seeds)}


def another_process_saves_meanwhile(monkeypatch, out, seeds, replace=False):
    """Make the next save_demos call's write be interrupted, between its temporary folder's fsync and its swap,
    by a whole save of ``seeds`` to ``out`` by another process (another pid)."""
    import os

    from drs_torchrl.demos import store

    real_fsync, pid = store.fsync_tree, os.getpid()

    def fsync_then_other_save(path):
        real_fsync(path)
        monkeypatch.setattr(store, "fsync_tree", real_fsync)
        with monkeypatch.context() as m:
            m.setattr(os, "getpid", lambda: pid + 1)
            store.save_demos(*fake_demos(*seeds), out, replace=replace)

    monkeypatch.setattr(store, "fsync_tree", fsync_then_other_save)


def test_demos_written_meanwhile_are_not_replaced_without_replace_and_the_new_ones_are_kept(tmp_path, monkeypatch):
    """drs-demos --out X twice at once, without --force: neither recording is lost, nor silently replaced."""
    from drs_torchrl.demos import DemosOutTakenError

    out = tmp_path / "my.demos"
    another_process_saves_meanwhile(monkeypatch, out, (7, 8))
    with pytest.raises(DemosOutTakenError) as e:
        save_demos(*fake_demos(0), out, replace=False)
    kept = tmp_path / "my-2.demos"
    assert e.value.kept == kept
    assert str(e.value) == (
        f"--out {out} already holds demonstrations (written by another process while these were recorded?); "
        f"the new demonstrations are saved at {kept} instead: use that path, pass --force to replace the earlier "
        "ones, or give another --out"
    )
    assert load_demos(out)[1]["seeds"] == [7, 8] and load_demos(kept)[1]["seeds"] == [0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["my-2.demos", "my.demos"]  # no temporaries left


def test_demos_replace_those_written_meanwhile_only_when_told(tmp_path, monkeypatch):
    out = tmp_path / "my.demos"
    another_process_saves_meanwhile(monkeypatch, out, (7, 8))
    assert save_demos(*fake_demos(0), out, replace=True) == out
    assert load_demos(out)[1]["seeds"] == [0]
    assert [p.name for p in tmp_path.iterdir()] == ["my.demos"]


def a_dead_pid() -> int:
    import os

    for pid in range(4_000_000, 4_100_000):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return pid
        except OSError:
            pass
    raise AssertionError("no free pid found")


def test_a_replace_stopped_between_its_renames_loses_nothing_and_load_names_both_copies(tmp_path, monkeypatch):
    """drs-demos --force killed after moving the earlier demonstrations aside and before the new ones took the
    name: the name is empty, both recordings are whole beside it, and reading the name says where they are."""
    import os

    from drs_torchrl.demos import leftover_notes, leftover_saves, store

    out = tmp_path / "my.demos"
    save_demos(*fake_demos(7), out)
    dead, real_rename = a_dead_pid(), store._rename_if_free
    calls = []

    def killed_on_the_second_try(src, dst):
        calls.append(dst)
        if len(calls) == 2:
            raise KeyboardInterrupt  # the process dies here: nothing after this line of save_demos runs
        return real_rename(src, dst)

    monkeypatch.setattr(store, "_rename_if_free", killed_on_the_second_try)
    monkeypatch.setattr(os, "getpid", lambda: dead)
    with pytest.raises(KeyboardInterrupt):
        save_demos(*fake_demos(0), out, replace=True)
    monkeypatch.undo()
    new, old = tmp_path / f"my.demos.tmp-{dead}", tmp_path / f"my.demos.old-{dead}"
    assert not out.exists() and leftover_saves(out) == [(new, True), (old, True)]
    with pytest.raises(DemoError) as e:
        load_demos(out)
    assert str(e.value) == (
        f"{out} does not exist, but a drs-demos save to it stopped midway and left new demonstrations that had not "
        f"taken the name yet at {new} and the ones it replaced at {old}: move the one you want into place "
        f"(mv {new} {out}), or record them again"
    )
    assert load_demos(new)[1]["seeds"] == [0] and load_demos(old)[1]["seeds"] == [7]  # both whole
    half = tmp_path / f"my.demos.tmp-{dead}0"  # another save, killed before its meta.json (a dead pid too)
    (half / "states").mkdir(parents=True)
    (tmp_path / f"my.demos.tmp-{os.getpid()}").mkdir()  # a save running now (this process) is not a leftover
    assert leftover_notes(out) == [
        f"{new} holds new demonstrations that had not taken the name yet, left whole by a save to my.demos that "
        f"stopped midway; use them (mv {new} OTHER.demos) or delete the folder",
        f"{half} is what a stopped save to my.demos left half written; delete it (rm -r {half})",
        f"{old} holds the ones it replaced, left whole by a save to my.demos that stopped midway; use them "
        f"(mv {old} OTHER.demos) or delete the folder",
    ]


def test_drs_demos_names_what_a_stopped_save_left_beside_its_out_and_keeps_it(tmp_path, monkeypatch, capsys):
    from drs_torchrl.tools import demos as app

    out = tmp_path / "my.demos"
    left = save_demos(*fake_demos(5), tmp_path / "x.demos").rename(tmp_path / f"my.demos.tmp-{a_dead_pid()}")
    monkeypatch.setattr(app, "record_demos", lambda fam, variant, num, *, seed, **kw: fake_demos(seed))
    assert app.main(["--num", "1", "--seed", "3", "--out", str(out)]) == 0
    assert f"drs-demos: note: {left} holds new demonstrations" in capsys.readouterr().err
    assert load_demos(out)[1]["seeds"] == [3] and load_demos(left)[1]["seeds"] == [5]


def test_drs_demos_out_keeps_demonstrations_another_process_wrote_meanwhile(tmp_path, monkeypatch, capsys):
    """The repro: drs-demos --out X while another drs-demos writes X; the second exits 2, both recordings kept."""
    from drs_torchrl.tools import demos as app

    out = tmp_path / "dd" / "my.demos"

    def record_while_another_process_saves(fam, variant, num, *, seed, **kw):
        save_demos(*fake_demos(0), out)  # the first drs-demos finishes while this one records
        return fake_demos(*range(seed, seed + num))

    monkeypatch.setattr(app, "record_demos", record_while_another_process_saves)
    assert app.main(["--num", "2", "--seed", "7", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"drs-demos: error: --out {out} already holds demonstrations") and "--force" in err
    assert load_demos(out)[1]["seeds"] == [0] and load_demos(out.with_name("my-2.demos"))[1]["seeds"] == [7, 8]
    assert app.main(["--num", "2", "--seed", "7", "--out", str(out), "--force"]) == 0
    assert load_demos(out)[1]["seeds"] == [7, 8]


# ------------------------------------------------ ManiSkill trajectory files (.h5 + .json) -> demos
H5_EPISODES = 2  # solved by the motion planner; one more random-action episode that does not succeed


@pytest.fixture(scope="module")
def maniskill_h5(tmp_path_factory):
    """A real ManiSkill trajectory file: ManiSkill's RecordEpisode around PickCubeSized-v1 (2 cm cube),
    driven by ManiSkill's motion-planning solver (2 episodes) and by random actions (1 episode)."""
    import gymnasium as gym
    import mani_skill.envs  # noqa: F401
    from mani_skill.examples.motionplanning.panda.solutions.pick_cube import solve
    from mani_skill.utils.wrappers.record import RecordEpisode

    import drs_torchrl.envs.variants  # noqa: F401

    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("h5")
    env = gym.make(
        "PickCubeSized-v1",
        obs_mode="state",
        control_mode="pd_joint_pos",
        num_envs=1,
        sim_backend="physx_cpu",
        render_mode=None,
        max_episode_steps=300,
        cube_half_size=0.02,
    )
    env = RecordEpisode(
        env,
        str(out),
        trajectory_name="pick",
        save_trajectory=True,
        save_video=False,
        save_on_reset=False,
        source_type="motionplanning",
    )
    for seed in range(H5_EPISODES):
        solve(env, seed=seed)
        env.flush_trajectory()
    env.reset(seed=7)
    gen = torch.Generator().manual_seed(0)
    for _ in range(15):
        env.step(torch.rand(1, 8, generator=gen) * 2 - 1)
    env.flush_trajectory()
    env.close()
    return out / "pick.h5"


@pytest.mark.sim
def test_maniskill_h5_converts_to_demos_matching_the_recording(maniskill_h5, pick_cube, tmp_path):
    import h5py

    from drs_torchrl.tools.demos import main
    from drs_torchrl.demos import load_maniskill_h5

    states, meta = load_maniskill_h5(maniskill_h5, pick_cube, "cube_2cm", progress=False)
    r = meta["replay"]
    assert meta["episodes"] == H5_EPISODES and r["skipped_unsuccessful"] == 1 and r["episode_ids"] == [0, 1]
    # a CPU recording replays exactly: no state had to be corrected, observations and success labels agree
    assert r["state_corrections"] == 0 and r["max_state_error"] < 1e-5
    assert r["max_recorded_obs_error"] < 1e-5 and r["success_label_mismatches"] == 0
    assert meta["shapes"] == {"observation": 42, "stage_indicators": 3}
    with h5py.File(maniskill_h5) as f:
        for i, n in enumerate(meta["lengths"]):
            ep = states[states["episode"] == i]
            assert ep.shape[0] == n
            recorded = torch.as_tensor(f[f"traj_{i}/obs"][()])[1 : n + 1]
            assert torch.allclose(ep["observation"], recorded, atol=1e-5)
            success = torch.as_tensor(f[f"traj_{i}/success"][()])[:n]
            assert torch.equal(ep["success"].reshape(-1), success)
            assert bool(success[-1]) and not bool(success[:-1].any())  # cut at the first success
            assert int(ep["stage"][-1]) == 3 and bool(ep["is_grasped"].any())
    check_demos(meta, pick_cube, {"observation": 42, "stage_indicators": 3})

    out = tmp_path / "from_h5.demos"
    assert (
        main(["--from-h5", str(maniskill_h5), "--family", "pick_cube", "--variant", "cube_2cm", "--out", str(out)]) == 0
    )
    episodes, saved = load_demos(out)
    assert len(episodes) == H5_EPISODES and saved["lengths"] == meta["lengths"]
    assert torch.equal(torch.cat([e["observation"] for e in episodes]), states["observation"])


@pytest.mark.sim
def test_maniskill_h5_errors_name_the_problem(maniskill_h5, pick_cube, tmp_path, capsys):
    import shutil

    from drs_torchrl.tools.demos import main
    from drs_torchrl.demos import load_maniskill_h5
    from drs_torchrl.tasks import get_family

    with pytest.raises(DemoError, match="no such trajectory file"):
        load_maniskill_h5(tmp_path / "missing.h5", pick_cube)
    assert main(["--from-h5", str(tmp_path / "missing.h5"), "--family", "pick_cube"]) == 2
    assert "no such trajectory file" in capsys.readouterr().err

    def copy(name, edit=None):
        h5 = tmp_path / f"{name}.h5"
        shutil.copy(maniskill_h5, h5)
        meta = json.loads(maniskill_h5.with_suffix(".json").read_text())
        if edit:
            edit(meta)
        h5.with_suffix(".json").write_text(json.dumps(meta))
        return h5

    lonely = tmp_path / "lonely.h5"
    shutil.copy(maniskill_h5, lonely)
    with pytest.raises(DemoError, match=r"lonely\.json is missing"):
        load_maniskill_h5(lonely, pick_cube)

    other = copy("other", lambda m: m["env_info"].update(env_id="PushCube-v1"))
    with pytest.raises(DemoError, match="recorded in 'PushCube-v1'.*runs 'PickCubeSized-v1'"):
        load_maniskill_h5(other, pick_cube)

    with pytest.raises(DemoError, match=r"cube_half_size=0\.02 \(the variant has cube_half_size=0\.015\)"):
        load_maniskill_h5(maniskill_h5, pick_cube, "cube_1_5cm")

    def bad_mode(m):
        for ep in m["episodes"]:
            ep["control_mode"] = "pd_teleport"

    with pytest.raises(DemoError, match="control mode 'pd_teleport'"):
        load_maniskill_h5(copy("mode", bad_mode), pick_cube, "cube_2cm", progress=False)

    with pytest.raises(DemoError, match="not a ManiSkill family"):
        load_maniskill_h5(maniskill_h5, get_family("half_cheetah"))


# ------------------------------------------------------------------ a trained policy as demonstrator
def _policy_run(tmp_path, family_name: str, env_cfg: dict):
    """A run directory as drs-learn leaves it: checkpoints/policy.pt (an untrained SAC actor) + config.yaml."""
    from omegaconf import OmegaConf

    from drs_torchrl.envs.factory import make_family_env
    from drs_torchrl.models import POLICY_FORMAT, make_sac_modules
    from drs_torchrl.tasks import get_family

    torch.manual_seed(0)
    env = make_family_env(get_family(family_name), "train", seed=0, max_episode_steps=env_cfg.get("max_episode_steps"))
    actor, _ = make_sac_modules(env.observation_spec, env.action_spec, ["observation", "stage_indicators"], [32, 32])
    env.close()
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    torch.save(
        {
            "format": POLICY_FORMAT,
            "version": 1,
            "frames": 0,
            "family": family_name,
            "policy_in_keys": ["observation", "stage_indicators"],
            "hidden": [32, 32],
            "actor": actor.state_dict(),
        },
        run / "checkpoints" / "policy.pt",
    )
    OmegaConf.save(OmegaConf.create({"env": env_cfg}), run / "config.yaml")
    return run


@pytest.mark.sim
def test_a_policy_records_demos_of_its_successful_episodes(tmp_path):
    """The paper's demonstrations come from trained RL agents (Appendix A); any family, solver or not."""
    from drs_torchrl.demos import record_policy_demos
    from drs_torchrl.tasks import get_family

    # HalfCheetah (no solver): success = the running return passed the threshold; 0.0 makes some episodes succeed
    run = _policy_run(
        tmp_path,
        "half_cheetah",
        {
            "family": "half_cheetah",
            "split": "test",
            "max_episode_steps": 40,
            "variant_overrides": {"success_return": 0.0},
        },
    )
    states, meta = record_policy_demos(run, None, 3, seed=1, deterministic=False, max_episodes=200, progress=False)
    assert meta["family"] == "half_cheetah" and meta["episodes"] == 3 and meta["solver"].startswith("policy:")
    assert meta["variant"] == "test"  # by default, the split the run trained on
    assert 3 <= meta["episodes_tried"] <= 200 and meta["success_rate"] == pytest.approx(3 / meta["episodes_tried"])
    assert meta["max_episode_steps"] == 40  # the run's env settings (config.yaml) were used
    path = save_demos(states, meta, tmp_path / "hc.demos")
    episodes, meta = load_demos(path)
    for ep, n in zip(episodes, meta["lengths"]):
        assert ep.shape[0] == n <= 40
        assert bool(ep["success"][-1]) and not bool(ep["success"][:-1].any())  # cut at the first success
        assert int(ep["stage"][-1]) == 1
    check_demos(meta, get_family("half_cheetah"), {"observation": 17, "stage_indicators": 1})


@pytest.mark.sim
def test_policy_demo_errors_name_the_problem(tmp_path, capsys):
    from drs_torchrl.tools.demos import main
    from drs_torchrl.demos import record_policy_demos
    from drs_torchrl.models import PolicyCheckpointError

    assert main(["--from-policy", str(tmp_path / "nowhere")]) == 2
    assert "no policy checkpoint there" in capsys.readouterr().err
    bad = tmp_path / "bad" / "checkpoints"
    bad.mkdir(parents=True)
    torch.save({"format": "drs-torchrl/reward", "weights": {}}, bad / "policy.pt")
    assert main(["--from-policy", str(bad.parent)]) == 2
    assert "not a drs-torchrl policy checkpoint" in capsys.readouterr().err
    # a policy that never succeeds: stopped after --max-episodes, with a hint
    run = _policy_run(
        tmp_path,
        "half_cheetah",
        {"family": "half_cheetah", "max_episode_steps": 5, "variant_overrides": {"success_return": 1.0e6}},
    )
    with pytest.raises(RuntimeError, match=r"succeeded in only 0 of 2 episodes.*--stochastic"):
        record_policy_demos(run, num=1, max_episodes=2, progress=False)
    # a ManiSkill family without a solver; the run's variant overrides (5-step valve episodes) apply
    tv = _policy_run(tmp_path / "tv", "turn_valve", {"family": "turn_valve", "variant_overrides": {"max_steps": 5}})
    with pytest.raises(RuntimeError, match="succeeded in only 0 of 2 episodes"):
        record_policy_demos(tv, num=1, max_episodes=2, progress=False)
    assert main(["--from-policy", str(tv), "--override", "max_steps=0"]) == 2
    assert "max_steps must be >= 1" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["--from-policy", str(run), "--override", "nokey"])
    assert e.value.code == 2 and "KEY=VALUE" in capsys.readouterr().err
    # a policy of another family, or for other sizes, is refused before any episode runs
    from drs_torchrl.envs.factory import make_family_env
    from drs_torchrl.models import load_policy
    from drs_torchrl.tasks import get_family

    env = make_family_env(get_family("half_cheetah"), "train", seed=0, max_episode_steps=5)
    try:
        with pytest.raises(PolicyCheckpointError, match="family 'half_cheetah', not 'pick_cube'"):
            load_policy(run, env.observation_spec, env.action_spec, family="pick_cube")
        ck = torch.load(run / "checkpoints" / "policy.pt", weights_only=True)
        first = next(k for k in ck["actor"] if k.endswith("weight"))
        ck["actor"][first] = torch.zeros(32, 99)
        torch.save(ck, run / "checkpoints" / "policy.pt")
        with pytest.raises(PolicyCheckpointError, match="does not fit this env"):
            load_policy(run, env.observation_spec, env.action_spec)
    finally:
        env.close()


@pytest.mark.sim
@pytest.mark.slow
def test_planner_demos_replayed_in_the_agents_controller(pick_cube, tmp_path):
    """--control-mode pd_ee_delta_pos (the agent's): ManiSkill's converter replays each solution in the agent's
    controller; the recorded actions, replayed from the same seed in that controller, succeed again."""
    import gymnasium as gym
    import numpy as np

    states, meta = record_demos(pick_cube, "cube_2cm", 1, seed=10, progress=False, control_mode="pd_ee_delta_pos")
    assert meta["actions"] == {"control_mode": "pd_ee_delta_pos", "size": 4}
    path = save_demos(states, meta, tmp_path / "ee.demos")
    (ep,), meta = load_demos(path)
    assert ep["action"].shape == (ep.shape[0], 4) and ep["state", "observation"].shape == (ep.shape[0], 42)
    # each row's "state" is the row before it (the first: the reset state, at stage 0)
    assert torch.equal(ep["state", "observation"][1:], ep["observation"][:-1]) and int(ep["state", "stage"][0]) == 0
    import mani_skill.envs  # noqa: F401

    import drs_torchrl.envs.variants  # noqa: F401

    args = pick_cube.env_args("cube_2cm")
    env = gym.make(
        args["env_id"],
        obs_mode="state",
        control_mode="pd_ee_delta_pos",
        num_envs=1,
        sim_backend="physx_cpu",
        max_episode_steps=1000,
        **args["env_kwargs"],
    )
    try:
        obs, _ = env.reset(seed=meta["seeds"][0])
        assert np.allclose(np.asarray(obs).reshape(-1), ep["state", "observation"][0].numpy(), atol=1e-5)
        for a in ep["action"]:
            obs, _, _, _, info = env.step(a.numpy())
        assert bool(info["success"])
    finally:
        env.close()


@pytest.mark.slow
@pytest.mark.sim
def test_a_stage_ablation_relabels_the_demonstrations_and_their_previous_states(pick_cube, tmp_path, capsys):
    """env.stages=[is_grasped, success] (Sec. 5.4.1) with three-stage demonstrations: every state's
    indicators and stage, and those of the state each action was taken in, are recomputed from the
    kept indicators, so the demonstrations' share of the SAC batch fits the agent's transitions."""
    from hydra import compose, initialize_config_dir

    from drs_torchrl.demos import restage_demos
    from drs_torchrl.apps.cli import conf_dir
    from drs_torchrl.apps.build import Run

    # in the agent's controller, as drs-demos records them by default, so they can share the SAC batch
    states, meta = record_demos(pick_cube, "cube_2cm", 2, seed=10, control_mode="pd_ee_delta_pos", progress=False)
    demo_dir = save_demos(states, meta, tmp_path / "pc_ee.demos")
    episodes, meta = load_demos(demo_dir)
    two, meta2 = restage_demos(episodes, meta, ["is_grasped", "success"])
    assert meta2["stage_keys"] == ["is_grasped", "success"] and meta2["shapes"]["stage_indicators"] == 2
    for old, ep in zip(episodes, two):
        assert ep["stage_indicators"].shape[-1] == ep["state", "stage_indicators"].shape[-1] == 2
        grasped, success = old["is_grasped"].float(), old["success"].float()
        assert torch.equal(ep["stage_indicators"], torch.cat([torch.maximum(grasped, success), success], -1))
        assert torch.equal(ep["stage"], ep["stage_indicators"].sum(-1, keepdim=True).long())
        assert torch.equal(ep["state", "stage_indicators"][1:], ep["stage_indicators"][:-1])
        assert torch.equal(ep["state", "stage"][1:], ep["stage"][:-1]) and int(ep["state", "stage"][0]) == 0
        assert int(ep["stage"][-1]) == 2 and int(old["stage"][-1]) == 3
    same, _ = restage_demos(episodes, meta, meta["stage_keys"])  # the recorded stages: nothing changes
    assert all(
        torch.equal(a["state", "stage_indicators"], b["state", "stage_indicators"]) for a, b in zip(episodes, same)
    )
    with pytest.raises(DemoError, match=r"\['is_lifted'\] are not among them"):
        restage_demos(episodes, meta, ["is_lifted", "success"])

    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        cfg_overrides = [
            "env=pick_cube",
            "+ablation=pnp_grasped_success",
            f"demos.path={demo_dir}",
            "demos.sac_share=0.25",
            "demos.stage_buffers=false",
            *tiny(frames=256, hidden=32),
            "algo.collector._target_=torchrl.collectors.Collector",
        ]
        cfg = compose("learn", overrides=cfg_overrides)
    tr = Run(cfg, "learn", tmp_path / "run")
    try:
        assert "recorded without" not in capsys.readouterr().out
        tr.run()  # three-stage demonstrations in a two-stage run's SAC batch: this used to fail at the first update
        batch = tr.updater.sample()
        assert batch["stage_indicators"].shape == (32, 2) and batch["next", "stage_indicators"].shape == (32, 2)
        assert int(batch["next", "stage"][-8:].max()) <= 2
    finally:
        tr.close()
    # a placed-threshold ablation with demonstrations recorded at the default threshold: said, with the fix
    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        cfg = compose(
            "learn", overrides=[*[o for o in cfg_overrides if not o.startswith("+ablation")], "+ablation=placed_5cm"]
        )
    Run(cfg, "learn", tmp_path / "run5").close()
    out = capsys.readouterr().out
    assert (
        "recorded without this run's env.variant_overrides placed_thresh=0.05 (recorded with the variant's default)"
        in out
    )
    assert "drs-demos --family pick_cube --override placed_thresh=0.05 --out NEW.demos" in out


def test_variant_mismatches_name_the_overrides_a_recording_lacks():
    from drs_torchrl.demos import variant_mismatches

    pooled = {
        "variant_kwargs": {
            "variants": [{"cube_half_size": 0.02, "goal_thresh": 0.05}, {"cube_half_size": 0.025, "goal_thresh": 0.05}]
        }
    }
    assert variant_mismatches(pooled, {"goal_thresh": 0.05}) == [] and variant_mismatches(pooled, None) == []
    assert variant_mismatches(pooled, {"goal_thresh": 0.1}) == ["goal_thresh=0.1 (recorded with 0.05)"]
    single = {"variant_kwargs": {"cube_half_size": 0.02}}
    assert variant_mismatches(single, {"goal_thresh": 0.05}) == [
        "goal_thresh=0.05 (recorded with the variant's default)"
    ]
    mixed = {"variant_kwargs": {"variants": [{"goal_thresh": 0.05}, {}]}}
    assert variant_mismatches(mixed, {"goal_thresh": 0.05}) == [
        "goal_thresh=0.05 (recorded with 0.05, the variant's default)"
    ]
