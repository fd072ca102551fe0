"""drs-study: runs named by a grid, dependencies, and re-invocation that skips what is finished."""

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from drs_torchrl.tools.study import StudyError, load_study, run_state
from budgets import tiny

BIN = Path(sys.executable).parent


def write(tmp_path, spec) -> Path:
    f = tmp_path / "study.yaml"
    f.write_text(yaml.safe_dump(spec, sort_keys=False))
    return f


def test_grid_names_runs_and_passes_every_override(tmp_path):
    root, runs = load_study(
        write(
            tmp_path,
            {
                "root": str(tmp_path / "runs"),
                "common": ["env=turn_valve"],
                "grid": {"seed": [0, 1], "algo.precision": ["fp32", "bf16"]},
                "runs": [
                    {
                        "name": "reuse",
                        "app": "reuse",
                        "args": ["reward.checkpoint=<root>/x/reward.pt"],
                        "needs": ["seed-0_precision-fp32"],
                    }
                ],
            },
        )
    )
    assert [r.name for r in runs] == [
        "seed-0_precision-fp32",
        "seed-0_precision-bf16",
        "seed-1_precision-fp32",
        "seed-1_precision-bf16",
        "reuse",
    ]
    assert runs[1].args == ["env=turn_valve", "seed=0", "algo.precision=bf16"]
    assert runs[-1].app == "reuse" and runs[-1].args[-1] == f"reward.checkpoint={tmp_path / 'runs'}/x/reward.pt"


@pytest.mark.parametrize(
    "spec,message",
    [
        ({"grid": {"seed": [0]}}, "root"),
        ({"root": "r"}, "no runs"),
        ({"root": "r", "runs": [{"name": "a"}, {"name": "a"}]}, "appear twice"),
        # the seed left unchanged in a copied line: a "second seed" that is the same run (a later override wins)
        (
            {
                "root": "r",
                "runs": [{"name": "x_s0", "args": ["seed=0"]}, {"name": "x_s1", "args": ["seed=1", "seed=0"]}],
            },
            "runs x_s0 and x_s1 have the same app and settings, so they would train the same run twice",
        ),
        ({"root": "r", "runs": [{"name": "a", "needs": ["b"]}]}, "needs \\['b'\\]"),
        ({"root": "r", "runs": [{"name": "a", "app": "train"}]}, "learn or reuse"),
        ({"root": "r", "gird": {}}, "unknown keys"),
        # a misspelt key of a run would be dropped: the run would not wait for its need, or run as drs-learn
        ({"root": "r", "runs": [{"name": "a", "need": ["b"]}, {"name": "b"}]}, "run a: unknown keys \\['need'\\]"),
        ({"root": "r", "runs": [{"name": "a", "appp": "reuse"}]}, "run a: unknown keys \\['appp'\\]"),
        # a string where a list belongs would be read letter by letter
        ({"root": "r", "runs": [{"name": "a"}, {"name": "b", "needs": "a"}]}, "run b: needs must be a list"),
        ({"root": "r", "runs": [{"name": "a", "args": "seed=0"}]}, "run a: args must be a list"),
        ({"root": "r", "common": "env=turn_valve", "runs": [{"name": "a"}]}, "common must be a list"),
        (
            {"root": "r", "runs": [{"name": "a_s0"}], "figures": {"main": {"groups": ["b"]}}},
            "groups \\['b'\\] name no run.*its groups: a",
        ),
        ({"root": "r", "runs": [{"name": "a_s0"}], "figures": {"main": {"groups": []}}}, "non-empty 'groups'"),
        ({"root": "r", "runs": [{"name": "a_s0"}], "figures": {"../x": {"groups": ["a"]}}}, "plain folder name"),
        (
            {"root": "r", "runs": [{"name": "a_s0"}], "figures": {"m": {"groups": ["a"], "colour": 1}}},
            "unknown keys \\['colour'\\]",
        ),
        (
            {"root": "r", "runs": [{"name": "a_s0"}], "figures": {"m": {"groups": ["a"], "labels": {"b": "B"}}}},
            "labels for \\['b'\\]",
        ),
        (
            {
                "root": "r",
                "runs": [{"name": "a_s0"}, {"name": "b_s0", "args": ["seed=1"]}],
                "figures": {"m": {"groups": ["a", "b"], "labels": {"a": "b"}}},
            },
            "drawn as one",
        ),
    ],
)
def test_bad_study_files_are_refused_by_name(tmp_path, spec, message):
    with pytest.raises(StudyError, match=message):
        load_study(write(tmp_path, spec))


def test_a_file_that_is_not_yaml_is_refused(tmp_path):
    (tmp_path / "x.pt").write_bytes(bytes(range(256)))
    with pytest.raises(StudyError, match="not a YAML study file"):
        load_study(tmp_path / "x.pt")
    with pytest.raises(StudyError, match="does not exist"):
        load_study(tmp_path / "missing.yaml")


def test_run_state_tells_finished_interrupted_and_broken_runs_apart(tmp_path):
    d = tmp_path / "r"
    assert run_state(d) == "new"
    d.mkdir()
    (d / "train.csv").write_text("step\n")
    assert run_state(d) == "broken"  # started, never reached a checkpoint
    (d / "checkpoints" / "state").mkdir(parents=True)
    (d / "checkpoints" / "state" / "COMPLETE").write_text("64")
    (d / "config.yaml").write_text("total_frames: 128\n")
    (d / "summary.json").write_text(json.dumps({"frames": 64, "interrupted": True}))
    assert run_state(d) == "resumable"
    (d / "summary.json").write_text(json.dumps({"frames": 128, "interrupted": False}))
    assert run_state(d) == "finished"
    assert run_state(d, want_frames=512) == "resumable"  # the study file now asks for more: resumed to it
    assert run_state(d, want_frames=64) == "finished"
    (d / "config.yaml").write_text("total_frames: 256\n")  # extended: not finished any more
    assert run_state(d) == "resumable"
    for rule in ("stopped_at_success", "stopped_at_eval_success"):  # ended early by its own stopping rule
        (d / "summary.json").write_text(json.dumps({"frames": 128, "interrupted": False, rule: {"frames": 128}}))
        assert run_state(d) == "finished"


def test_a_resumed_run_keeps_the_study_files_budget_and_stopping_rules(tmp_path):
    from drs_torchrl.tools.study import Run, command

    run = Run(
        name="a", app="reuse", args=["seed=0", "total_frames=9", "eval.stop_at_success=0.8", "+eval.stop_streak=2"]
    )
    cmd = command(run, tmp_path / "a", "resumable")
    assert cmd[1:] == [f"resume={tmp_path / 'a'}", "total_frames=9", "eval.stop_at_success=0.8", "+eval.stop_streak=2"]


@pytest.mark.sim
@pytest.mark.slow
def test_a_study_runs_learn_then_reuse_and_a_second_call_skips_both(tmp_path):
    small = [*tiny(eval_episodes=0), "+env.variant_overrides.goal_thresh=0.08"]
    f = write(
        tmp_path,
        {
            "root": str(tmp_path / "runs"),
            "common": small,
            "runs": [
                {"name": "learn", "args": ["seed=1"]},
                {
                    "name": "reuse",
                    "app": "reuse",
                    "needs": ["learn"],
                    "args": ["reward=drs", "reward.checkpoint=<root>/learn/checkpoints/reward.pt", "env.split=train"],
                },
            ],
        },
    )
    p = subprocess.run([str(BIN / "drs-study"), str(f), "--jobs", "2"], capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, (
        p.stdout + p.stderr + "".join(x.read_text()[-1500:] for x in (tmp_path / "runs" / "logs").glob("*.log"))
    )
    assert "all 2 runs finished" in p.stdout
    for name in ("learn", "reuse"):
        assert run_state(tmp_path / "runs" / name) == "finished"
    assert json.loads((tmp_path / "runs" / "reuse" / "summary.json").read_text())["phase"] == "reuse"
    p = subprocess.run([str(BIN / "drs-study"), str(f)], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0 and p.stdout.count("finished, skipped") == 2


def _fake_run(
    d: Path, reward: str, seed: int, success: list[float], frames: int, *, app="reuse", complete=False, split="test"
):
    """A run directory as drs-learn / drs-reuse leave it (the report reads files only)."""
    (d / "checkpoints" / "state").mkdir(parents=True)
    if complete:
        (d / "checkpoints" / "state" / "COMPLETE").write_text("")
    (d / "config.yaml").write_text(
        f"phase: {app}\nseed: {seed}\ntotal_frames: {frames}\nreward:\n  name: {reward}\n"
        f"  checkpoint: {Path.cwd().resolve()}/results/x/reward.pt\nenv:\n  split: {split}\n"
    )
    steps = [1000 * (i + 1) for i in range(len(success))]
    (d / "eval.csv").write_text(
        "step,episodes,success_rate,reach_stage_1\n" + "".join(f"{s},10,{y},{y}\n" for s, y in zip(steps, success))
    )
    (d / "train.csv").write_text(
        "step,success_rate,reach_stage_1\n" + "".join(f"{s},{y},{y}\n" for s, y in zip(steps, success))
    )
    if app == "learn":
        (d / "checkpoints" / "reward.pt").write_bytes(b"reward")
        (d / "checkpoints" / "policy.pt").write_bytes(b"policy")


def test_report_copies_the_record_and_compares_by_run_name(tmp_path, capsys):
    from drs_torchrl.tools.study import group_name, main

    assert [
        group_name(n)
        for n in (
            "drs_s0",
            "one_stage_s12",
            "seed-1",
            "precision-bf16_seed-1",
            "dense-train_s0",
            "seed-0_precision-fp32",
            "a-1_seed-2_b-3",
        )
    ] == ["drs", "one_stage", "seed-1", "precision-bf16", "dense-train", "precision-fp32", "a-1_b-3"]
    root = tmp_path / "runs"
    study = write(
        tmp_path,
        {
            "root": str(root),
            "app": "reuse",
            "common": ["total_frames=3000"],
            "runs": [
                {"name": "learn_s0", "app": "learn", "args": []},
                {"name": "drs_s0", "args": ["seed=0"]},
                {"name": "drs_s1", "args": ["seed=1"]},
                {"name": "one_stage_s0", "args": ["ablation=one_stage"]},  # reward.name drs too: grouped by its name
                {"name": "sparse_s0", "args": ["reward=sparse"]},
                {"name": "dense-train_s0", "args": ["env.split=train"]},
            ],
        },
    )  # the baseline checked where the reward was learned
    _fake_run(root / "learn_s0", "drs", 0, [0.0, 1.0, 1.0], 3000, app="learn", complete=True, split="train")
    _fake_run(root / "dense-train_s0", "dense", 0, [0.5], 1000, complete=True, split="train")
    _fake_run(root / "drs_s0", "drs", 0, [0.0, 0.6, 1.0], 3000, complete=True)
    _fake_run(root / "drs_s1", "drs", 1, [0.2, 0.4], 3000, complete=True)  # still running (or interrupted)
    _fake_run(root / "one_stage_s0", "drs", 0, [0.0, 0.0, 0.0], 3000)
    # sparse_s0 has not started
    for name in ("drs_s0", "one_stage_s0", "learn_s0"):
        (root / name / "summary.json").write_text(json.dumps({"frames": 3000, "interrupted": False}))
    # finished early on its own criterion (stop_at_success), 1k steps
    (root / "dense-train_s0" / "summary.json").write_text(
        json.dumps({"frames": 1000, "interrupted": False, "stopped_at_success": True})
    )
    out = tmp_path / "results"
    assert main([str(study), "--report", str(out)]) == 0
    # the record, never the training state; the checkout's absolute path is gone from the copies
    assert sorted(p.name for p in (out / "run_files").iterdir()) == [
        "dense-train_s0",
        "drs_s0",
        "drs_s1",
        "learn_s0",
        "one_stage_s0",
    ]
    assert not list(out.rglob("state")) and (out / "run_files" / "learn_s0" / "reward.pt").read_bytes() == b"reward"
    assert "checkpoint: results/x/reward.pt" in (out / "run_files" / "drs_s0" / "config.yaml").read_text()
    status = (out / "status.md").read_text()
    assert "| `drs_s0` | reuse | finished | 3,000 (3000) | 1.00 at 3000 |" in status
    assert "| `drs_s1` | reuse | resumable | 2,000 (3000) | 0.40 at 2000 |" in status
    assert "| `sparse_s0` | reuse | new | 0 (3000) | - |" in status
    md = (out / "compare.md").read_text()
    # the comparison holds the finished runs: drs_s1, still going, is in status.md and run_files but would cut the horizon
    assert "| drs | 1 (0) |" in md and "| one_stage | 1 (0) |" in md and "learn" not in md.split("Runs:")[0]
    assert "drs_s1" not in md
    assert (out / "compare.png").is_file() and (out / "learn" / "compare.md").is_file()
    # a reuse run on another split is compared apart: the held-out runs' AUC horizon is theirs (3k), not its 1k
    assert "dense-train" not in md and "success AUC to 3k" in md
    assert "| dense-train | 1 (0) |" in (out / "on_train" / "compare.md").read_text()
    # a report into the run root would mix the record with the runs
    assert main([str(study), "--report", str(root / "r")]) == 2
    assert "inside the study's run root" in capsys.readouterr().err


def test_report_draws_the_study_files_figures_with_their_groups_order_and_labels(tmp_path, capsys):
    """A study of many groups names curated figures: only their groups, in their order, with display labels."""
    from drs_torchrl.tools.study import main

    root = tmp_path / "runs"
    study = write(
        tmp_path,
        {
            "root": str(root),
            "app": "reuse",
            "common": ["total_frames=3000"],
            "runs": [
                {"name": "drs_s0", "args": ["seed=0"]},
                {"name": "drs_s1", "args": ["seed=1"]},
                {"name": "sparse_s0", "args": ["reward=sparse"]},
                {"name": "ablation_s0", "args": ["ablation=one_stage"]},
                {"name": "gail_s0", "args": ["reward=gail"]},
            ],
            "figures": {
                "main": {"title": "held-out variants", "groups": ["sparse", "drs", "gail"], "labels": {"drs": "DrS"}},
                "ablations": {"groups": ["drs", "ablation"]},
            },
        },
    )
    _fake_run(root / "drs_s0", "drs", 0, [0.0, 0.6, 1.0], 3000, complete=True)
    _fake_run(root / "drs_s1", "drs", 1, [0.0, 0.2, 0.6], 3000, complete=True)
    _fake_run(root / "sparse_s0", "sparse", 0, [0.0, 0.0, 0.0], 3000, complete=True)
    _fake_run(root / "ablation_s0", "drs", 0, [0.0, 0.0, 0.5], 3000, complete=True)
    for name in ("drs_s0", "drs_s1", "sparse_s0", "ablation_s0"):
        (root / name / "summary.json").write_text(json.dumps({"frames": 3000, "interrupted": False}))
    # gail_s0 has not started: the figure is drawn without it and the report says so
    out = tmp_path / "results"
    assert main([str(study), "--report", str(out)]) == 0
    assert "figure main: no finished runs yet for ['gail']" in capsys.readouterr().err
    md = (out / "figures" / "main" / "compare.md").read_text()
    assert md.startswith("**held-out variants**")
    table = [line for line in md.splitlines() if line.startswith("| ") and "(" in line and "runs (seeds)" not in line]
    assert [line.split(" | ")[0] for line in table[:2]] == ["| sparse", "| DrS"]  # the figure's order and labels
    assert "| DrS | 2 (0, 1) |" in md and "ablation" not in md.split("Runs:")[0]
    assert (out / "figures" / "main" / "compare.png").is_file()
    abl = (out / "figures" / "ablations" / "compare.md").read_text()
    assert "| drs | 2 (0, 1) |" in abl and "| ablation | 1 (0) |" in abl and "sparse" not in abl.split("Runs:")[0]


def test_a_fresh_checkout_skips_what_its_record_holds_and_reuses_its_rewards(tmp_path, capsys):
    """Training states are not committed: a run whose directory is gone but whose committed record says
    it finished is ``recorded`` (skipped, satisfies ``needs``), ``<reward:NAME>`` falls back to the
    record's reward.pt, and a report keeps the record instead of calling the run new."""
    from drs_torchrl.tools.study import load_record, main, resolve_args, study_state

    root, out = tmp_path / "runs", tmp_path / "results"
    study = write(
        tmp_path,
        {
            "root": str(root),
            "app": "reuse",
            "record": str(out),
            "common": ["total_frames=3000"],
            "runs": [
                {"name": "learn_s0", "app": "learn", "args": []},
                {
                    "name": "drs_s0",
                    "args": ["reward.checkpoint=<reward:learn_s0>", "init_from=<policy:learn_s0>"],
                    "needs": ["learn_s0"],
                },
                {"name": "sparse_s0", "args": ["reward=sparse"]},
                {"name": "dense_s0", "args": ["reward=dense"]},
            ],
        },
    )
    _, runs = load_study(study)
    record = load_record(study)
    assert record == out
    by = {r.name: r for r in runs}
    assert resolve_args(by["drs_s0"], root, record) == [
        "total_frames=3000",
        f"reward.checkpoint={root}/learn_s0/checkpoints/reward.pt",
        f"init_from={root}/learn_s0/checkpoints/policy.pt",
    ]
    for name, frames in (("learn_s0", 3000), ("sparse_s0", 2000)):  # sparse_s0 was interrupted, its state lost
        _fake_run(
            root / name,
            "drs" if name == "learn_s0" else "sparse",
            0,
            [0.0, 0.5, 1.0][: frames // 1000],
            3000,
            app="learn" if name == "learn_s0" else "reuse",
        )
        (root / name / "summary.json").write_text(json.dumps({"frames": frames, "interrupted": frames < 3000}))
    assert main([str(study), "--report", str(out)]) == 0
    import shutil

    shutil.rmtree(root)  # the next session's fresh checkout: the records only
    assert [study_state(root, record, by[n]) for n in ("learn_s0", "drs_s0", "sparse_s0", "dense_s0")] == [
        "recorded",
        "new",
        "new",
        "new",
    ]
    assert resolve_args(by["drs_s0"], root, record)[1:] == [
        f"reward.checkpoint={out}/run_files/learn_s0/reward.pt",
        f"init_from={out}/run_files/learn_s0/policy.pt",
    ]
    # the record is re-read, not overwritten: learn_s0 stays in the record and in the comparison
    assert main([str(study), "--report", str(out)]) == 0
    status = (out / "status.md").read_text()
    assert "| `learn_s0` | learn | recorded | 3,000 (3000) | 1.00 at 3000 |" in status
    assert "| `sparse_s0` | reuse | new (an unfinished earlier record) | 2,000 (3000) | 0.50 at 2000 |" in status
    assert "| `dense_s0` | reuse | new | 0 (3000) | - |" in status
    assert (out / "run_files" / "learn_s0" / "reward.pt").read_bytes() == b"reward"
    assert (out / "run_files" / "learn_s0" / "policy.pt").read_bytes() == b"policy"
    # its only reuse run is an unfinished record: nothing to compare yet
    assert not (out / "compare.md").exists()
    capsys.readouterr()
    assert main([str(study), "--status"]) == 0
    assert "  recorded  " in capsys.readouterr().out


def test_a_run_another_study_call_is_training_is_neither_restarted_nor_deleted(tmp_path, capsys):
    from drs_torchrl.tools.study import main, pid_file

    root = tmp_path / "runs"
    f = write(tmp_path, {"root": str(root), "runs": [{"name": "a", "args": ["total_frames=1000"]}]})
    (root / "a").mkdir(parents=True)
    (root / "a" / "train.csv").write_text("step\n")  # started, no checkpoint yet: "broken" if nobody trains it
    (root / "logs").mkdir()
    # a stand-in for the training process, whose command line names the run's directory as drs-learn's does
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)", f"hydra.run.dir={root / 'a'}"])
    try:
        for _ in range(200):  # until the child has exec'd the command above
            if str(root / "a") in Path(f"/proc/{proc.pid}/cmdline").read_bytes().decode():
                break
            time.sleep(0.05)
        pid_file(root, "a").write_text(f"{proc.pid}\n")
        assert main([str(f), "--status"]) == 0
        assert capsys.readouterr().out.split()[0] == "running"
        assert main([str(f)]) == 0
        assert f"a: being trained by another call (pid {proc.pid}), skipped" in capsys.readouterr().out
        assert (root / "a" / "train.csv").is_file()  # not deleted as broken, not started a second time
        assert not (root / "logs" / "a.log").exists()
    finally:
        proc.kill()
        proc.wait()
    # once that process is gone (or the pid names another program) the run is the study's again
    assert main([str(f), "--status"]) == 0
    assert capsys.readouterr().out.split()[0] == "broken"
    pid_file(root, "a").write_text(f"{os.getpid()}\n")  # a live pid whose program is not this run's (a recycled pid)
    assert main([str(f), "--status"]) == 0
    assert capsys.readouterr().out.split()[0] == "broken"


def test_a_run_started_elsewhere_after_the_study_looked_is_left_alone(tmp_path, capsys, monkeypatch):
    """Between reading the states and starting a run, another process may have started it (another study call,
    or drs-learn by hand into the run's directory, which holds its lock): it is skipped, not deleted as broken."""
    from drs_torchrl.tools import study

    root = tmp_path / "runs"
    f = write(tmp_path, {"root": str(root), "runs": [{"name": "a", "args": ["total_frames=1000"]}]})
    real_state = study.study_state

    def state_then_started(root_, record, run):  # the states are read, then another process takes the run
        state = real_state(root_, record, run)
        if holder:
            return state
        script = f"from drs_torchrl.runtime.rundir import lock_run_dir; lock_run_dir({str(root / 'a')!r}); "
        script += f"open({str(root / 'a' / 'train.csv')!r}, 'w').write('step\\n'); print('locked', flush=True); "
        script += "import time; time.sleep(60)"
        holder.append(subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True))
        assert holder[-1].stdout.readline().strip() == "locked"
        return state

    holder: list = []
    monkeypatch.setattr(study, "study_state", state_then_started)
    try:
        assert study.main([str(f)]) == 0
        out = capsys.readouterr().out
        assert "a: being trained by another process, skipped" in out and "a: starting" not in out
        assert (root / "a" / "train.csv").read_text() == "step\n"  # not deleted as a broken run
        assert not (root / "logs" / "a.log").exists()
    finally:
        for p in holder:
            p.kill()
            p.wait()


def test_a_reward_reference_must_be_among_the_runs_needs(tmp_path):
    with pytest.raises(StudyError, match="does not list learn in its needs"):
        load_study(
            write(
                tmp_path,
                {"root": "r", "runs": [{"name": "learn"}, {"name": "a", "args": ["reward.checkpoint=<reward:learn>"]}]},
            )
        )
    with pytest.raises(StudyError, match="<policy:learn> but does not list"):
        load_study(
            write(
                tmp_path,
                {"root": "r", "runs": [{"name": "learn"}, {"name": "a", "args": ["init_from=<policy:learn>"]}]},
            )
        )


def test_a_run_with_a_bad_override_or_missing_file_stops_the_study_before_anything_starts(tmp_path, capsys):
    from drs_torchrl.tools.study import main

    good = {"name": "ok", "args": ["total_frames=1000"]}
    reuse = {"name": "reuse", "app": "reuse", "args": ["reward=drs", "reward.checkpoint=<reward:ok>"], "needs": ["ok"]}
    spec = {
        "root": str(tmp_path / "runs"),
        "common": ["env=turn_valve"],
        "runs": [
            good,
            reuse,  # a checkpoint another run will write need not exist yet
            {"name": "typo", "args": ["algo.gama=0.9"]},
            {"name": "no_demos", "args": [f"demos.path={tmp_path / 'missing.demos'}"]},
            {"name": "bad_value", "args": ["stop_at_success=2"]},
            {"name": "no_ablation", "args": ["+ablation=nope"]},
            {"name": "added_key", "args": ["+algo.lr=1e-3"]},  # Hydra adds it; nothing would read it
            {
                "name": "static_ckpt",
                "app": "reuse",
                "args": ["reward=dense", "reward.checkpoint=<reward:ok>"],
                "needs": ["ok"],
            },
        ],
    }
    f = write(tmp_path, spec)
    assert main([str(f), "--check"]) == 2
    out = capsys.readouterr().out
    lines = {ln.split()[1].rstrip(":"): ln for ln in out.splitlines()}
    assert lines["ok"].split()[0] == "ok" and lines["reuse"].split()[0] == "ok"
    assert (
        "algo.gama" in lines["typo"]
        and "missing.demos: no such file (record them first: drs-demos --family" in lines["no_demos"]
    )
    assert "stop_at_success must be" in lines["bad_value"] and "ablation/nope" in lines["no_ablation"]
    assert "no setting 'algo.lr'" in lines["added_key"] and "algo.optim.lr" in lines["added_key"]
    assert "reward=dense is a static reward and reads no checkpoint" in lines["static_ckpt"]
    # running the study refuses as a whole, names every bad run, and creates nothing
    assert main([str(f)]) == 2
    err = capsys.readouterr().err
    assert (
        all(f"run {n}:" in err for n in ("typo", "no_demos", "bad_value", "no_ablation", "added_key", "static_ckpt"))
        and "nothing started" in err
    )
    assert not (tmp_path / "runs").exists()
    # the good runs alone pass the check
    assert main([str(f), "--check", "--only", "ok", "reuse"]) == 0


def test_status_counts_the_env_steps_and_hours_a_study_has_left(tmp_path, capsys):
    """What is left: the unfinished part of a resumable run, every step of a new one, nothing of a finished
    one, timed at the speed the run directories logged (a fresh checkout: the record's summaries)."""
    from drs_torchrl.tools.study import main, work_left

    root, out = tmp_path / "runs", tmp_path / "results"
    study = write(
        tmp_path,
        {
            "root": str(root),
            "app": "reuse",
            "record": str(out),
            "runs": [
                {"name": "done_s0", "args": ["total_frames=3000"]},
                {"name": "half_s0", "args": ["total_frames=4000"]},
                {"name": "new_s0", "args": ["total_frames=9000"]},
                {"name": "learn_s0", "app": "learn", "args": ["total_frames=2000"]},
            ],
        },
    )
    _fake_run(root / "done_s0", "dense", 0, [0.0, 0.5, 1.0], 3000, complete=True)
    (root / "done_s0" / "summary.json").write_text(
        json.dumps({"frames": 3000, "interrupted": False, "env_steps_per_s": 99.0})
    )
    _fake_run(root / "half_s0", "sparse", 0, [0.0], 4000, complete=True)  # resumable at 1000 of 4000
    # a run's speed is the median of its log rows once it has logged SPEED_ROWS of them (the warm-up rows run
    # 2-3x faster); a run with fewer rows does not count while another run or the record says more
    for d, speeds in (("done_s0", [9.0, 8.0, 2.0, 2.0, 2.0, 1.9]), ("half_s0", [7.0])):
        (root / d / "train.csv").write_text(
            "step,env_steps_per_s\n" + "".join(f"{1000 * (i + 1)},{v}\n" for i, v in enumerate(speeds))
        )
    _, runs = load_study(study)
    states = {"done_s0": "finished", "half_s0": "resumable", "new_s0": "new", "learn_s0": "new"}
    line = work_left(root, None, runs, states, jobs=2)
    # 3000 + 9000 + 2000 = 14,000 steps at done_s0's median row, 2.0 env steps/s: 7000 s
    assert line.startswith("left: 3 of 4 runs, at most 14,000 env steps (phase-1 runs stop early")
    assert (
        "at 2.0 env steps/s per run (median of 1 run directories here) about 1.9 h of runs, 58 min with --jobs 2"
        in line
    )
    assert main([str(study), "--status"]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1].startswith("left: 3 of 4 runs, at most 14,000 env steps")
    # a fresh checkout: no run directories, the speed comes from the record's summaries
    (out / "run_files" / "done_s0").mkdir(parents=True)
    (out / "run_files" / "done_s0" / "summary.json").write_text(json.dumps({"env_steps_per_s": 50.0}))
    states = {"done_s0": "recorded", "half_s0": "new", "new_s0": "new", "learn_s0": "new"}
    line = work_left(tmp_path / "elsewhere", out, runs, states, jobs=1)
    assert (
        "at most 15,000 env steps" in line
        and "at 50.0 env steps/s per run (median of 1 recorded runs) about 5 min of runs" in line
    )
    # only just-started runs here and no record: their last rows, said to be an upper bound
    fresh = {"done_s0": "finished", "half_s0": "new", "new_s0": "new", "learn_s0": "new"}
    (root / "done_s0" / "train.csv").write_text("step,env_steps_per_s\n1000,9.0\n")
    (root / "done_s0" / "summary.json").write_text(json.dumps({"frames": 3000, "interrupted": False}))
    line = work_left(root, None, runs, fresh)
    assert "at 9.0 env steps/s per run (median of 2 run directories here, under 5 log rows each" in line
    assert "an upper bound" in line
    # ... and with a record, the record's finished runs instead
    line = work_left(root, out, runs, fresh)
    assert "at 50.0 env steps/s per run (median of 1 recorded runs)" in line
    # a short run that finished here counts at its own summary's speed, not its warm-up row
    (root / "done_s0" / "summary.json").write_text(
        json.dumps({"frames": 3000, "interrupted": False, "env_steps_per_s": 99.0})
    )
    line = work_left(root, out, runs, fresh)
    assert "at 99.0 env steps/s per run (median of 1 run directories here)" in line
    assert work_left(root, None, runs, dict.fromkeys(states, "finished")) == "left: nothing, all 4 runs done"


def test_every_committed_study_file_loads_with_its_figures():
    """The study files the README points at parse, name their runs' needs and draw only groups they define."""
    from drs_torchrl.tools.study import load_figures

    files = sorted((Path(__file__).parents[1] / "results").rglob("study.yaml"))
    assert len(files) >= 2
    for f in files:
        load_figures(f)  # raises StudyError naming what is wrong
    pick = {fig.name: fig for fig in load_figures(Path(__file__).parents[1] / "results/reuse/pick_cube/study.yaml")}
    assert pick["main"].groups[:4] == ["drs-sacdemos", "dense", "semi_sparse", "sparse"]
