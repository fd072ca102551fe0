"""drs-study: runs named by a grid, dependencies, and re-invocation that skips what is finished."""
import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from drs_torchrl.study import StudyError, load_study, run_state

BIN = Path(sys.executable).parent


def write(tmp_path, spec) -> Path:
    f = tmp_path / "study.yaml"
    f.write_text(yaml.safe_dump(spec, sort_keys=False))
    return f


def test_grid_names_runs_and_passes_every_override(tmp_path):
    root, runs = load_study(write(tmp_path, {
        "root": str(tmp_path / "runs"), "common": ["env=turn_valve"],
        "grid": {"seed": [0, 1], "algo.precision": ["fp32", "bf16"]},
        "runs": [{"name": "reuse", "app": "reuse", "args": ["reward.checkpoint=<root>/x/reward.pt"], "needs": ["seed-0_precision-fp32"]}],
    }))
    assert [r.name for r in runs] == ["seed-0_precision-fp32", "seed-0_precision-bf16", "seed-1_precision-fp32",
                                      "seed-1_precision-bf16", "reuse"]
    assert runs[1].args == ["env=turn_valve", "seed=0", "algo.precision=bf16"]
    assert runs[-1].app == "reuse" and runs[-1].args[-1] == f"reward.checkpoint={tmp_path / 'runs'}/x/reward.pt"


@pytest.mark.parametrize("spec,message", [
    ({"grid": {"seed": [0]}}, "root"),
    ({"root": "r"}, "no runs"),
    ({"root": "r", "runs": [{"name": "a"}, {"name": "a"}]}, "appear twice"),
    ({"root": "r", "runs": [{"name": "a", "needs": ["b"]}]}, "needs \\['b'\\]"),
    ({"root": "r", "runs": [{"name": "a", "app": "train"}]}, "learn or reuse"),
    ({"root": "r", "gird": {}}, "unknown keys"),
])
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


@pytest.mark.sim
@pytest.mark.slow
def test_a_study_runs_learn_then_reuse_and_a_second_call_skips_both(tmp_path):
    tiny = ["total_frames=320", "algo.learning_starts=128", "algo.batch_size=32", "algo.hidden=[16,16]",
            "reward.disc.batch_size=16", "logger.interval=128", "eval.interval=100000", "eval.episodes=0",
            "checkpoint_interval=100000", "logger.tensorboard=false", "logger.progress_bar=false",
            "+env.variant_overrides.goal_thresh=0.08"]
    f = write(tmp_path, {"root": str(tmp_path / "runs"), "common": tiny, "runs": [
        {"name": "learn", "args": ["seed=1"]},
        {"name": "reuse", "app": "reuse", "needs": ["learn"],
         "args": ["reward=drs", "reward.checkpoint=<root>/learn/checkpoints/reward.pt", "env.split=train"]},
    ]})
    p = subprocess.run([str(BIN / "drs-study"), str(f), "--jobs", "2"], capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stdout + p.stderr + "".join(
        x.read_text()[-1500:] for x in (tmp_path / "runs" / "logs").glob("*.log"))
    assert "all 2 runs finished" in p.stdout
    for name in ("learn", "reuse"):
        assert run_state(tmp_path / "runs" / name) == "finished"
    assert json.loads((tmp_path / "runs" / "reuse" / "summary.json").read_text())["phase"] == "reuse"
    p = subprocess.run([str(BIN / "drs-study"), str(f)], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0 and p.stdout.count("finished, skipped") == 2
