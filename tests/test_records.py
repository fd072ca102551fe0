"""Committed records stand alone: every reuse record pins the reward it reused (reward.json: a committed file and
its sha256), drs-eval reads the pin and refuses a file whose hash differs, and drs-study --report writes it."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from drs_torchrl.tools.study import REWARD_PIN, RecordError, pinned_reward, sha256_file

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
# reuse records whose phase-1 reward was never committed (maze diagnostics): their pin says so
LOST = {
    "results/maze/before_nstep_fix/diagnostics/reuse-rel-s0",
    "results/maze/before_nstep_fix/diagnostics/reuse-scalar-s0",
    "results/maze/diagnostics/reuse-patch-s0",
    "results/maze/diagnostics/scale/reuse-patch-x0.1-s0",
}


def reuse_records() -> list[Path]:
    """Every committed record of a run that reused a learned reward (its config.yaml names reward.checkpoint)."""
    found = []
    for cfg in sorted((REPO / "results").rglob("config.yaml")):
        if ".hydra" in cfg.parts:
            continue
        c = yaml.safe_load(cfg.read_text())
        if isinstance(c, dict) and c.get("phase") == "reuse" and (c.get("reward") or {}).get("checkpoint"):
            found.append(cfg.parent)
    return found


def test_every_committed_reuse_record_pins_a_committed_reward_by_hash():
    records = reuse_records()
    assert len(records) >= 90  # 93 when the records were migrated (issue 47)
    lost, bad = set(), []
    for rec in records:
        name = str(rec.relative_to(REPO))
        pin_file = rec / REWARD_PIN
        if not pin_file.is_file():
            bad.append(f"{name}: no {REWARD_PIN}")
            continue
        pin = json.loads(pin_file.read_text())
        assert pin["ran_with"] == str(yaml.safe_load((rec / "config.yaml").read_text())["reward"]["checkpoint"]), name
        if pin["checkpoint"] is None:
            lost.add(name)
            continue
        assert not Path(pin["checkpoint"]).is_absolute() and pin["checkpoint"].startswith("results/"), name
        assert (REPO / pin["checkpoint"]).is_file(), f"{name}: {pin['checkpoint']} is not committed"
        try:
            assert pinned_reward(rec) == REPO / pin["checkpoint"]
        except RecordError as exc:
            bad.append(str(exc))
    assert not bad, "\n".join(bad)
    assert lost == LOST


def test_a_pin_refuses_a_reward_whose_hash_differs_and_one_never_committed(tmp_path):
    rec = tmp_path / "rec"
    rec.mkdir()
    reward = tmp_path / "reward.pt"
    reward.write_bytes(b"the reward")
    (rec / REWARD_PIN).write_text(
        json.dumps({"checkpoint": str(reward), "sha256": sha256_file(reward), "ran_with": "x"})
    )
    assert pinned_reward(rec) == reward
    reward.write_bytes(b"another reward")
    with pytest.raises(RecordError, match="sha256 differs"):
        pinned_reward(rec)
    (rec / REWARD_PIN).write_text(
        json.dumps({"checkpoint": "results/nowhere/reward.pt", "sha256": "0", "ran_with": "x"})
    )
    with pytest.raises(RecordError, match="not in this checkout"):
        pinned_reward(rec)
    (rec / REWARD_PIN).write_text(json.dumps({"checkpoint": None, "sha256": None, "ran_with": "runs/x/reward.pt"}))
    with pytest.raises(RecordError, match="was not committed"):
        pinned_reward(rec)
    assert pinned_reward(tmp_path) is None  # no pin: a run directory


RECORD = "results/reuse/pick_cube/run_files/placed_5cm_s0"  # its config.yaml names runs/reuse_pick_cube/... (gone)


def test_drs_eval_refuses_a_record_whose_reward_hash_differs_in_one_line(tmp_path, capsys):
    """(drs-eval's app in this process: the refusal comes before any env is built.)"""
    from drs_torchrl.apps.evaluate import main as drs_eval

    rec = tmp_path / "placed_5cm_s0"
    shutil.copytree(REPO / RECORD, rec)
    pin = json.loads((rec / REWARD_PIN).read_text())
    (rec / REWARD_PIN).write_text(json.dumps({**pin, "checkpoint": str(REPO / pin["checkpoint"]), "sha256": "0" * 64}))
    code = drs_eval([str(rec), "--split", "test", "--episodes", "1"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err.startswith("drs-eval: error: ") and err.count("\n") == 0 and "sha256 differs" in err, err
    assert not list(rec.glob("eval_*.json"))


@pytest.mark.slow
@pytest.mark.sim
def test_a_committed_reuse_record_evaluates_from_outside_the_checkout(tmp_path):
    """The record names runs/reuse_pick_cube/learn-placed_5cm_s0/checkpoints/reward.pt, which only existed on the machine
    that ran it; drs-eval takes the pinned committed copy (from any working directory)."""
    assert not (REPO / yaml.safe_load((REPO / RECORD / "config.yaml").read_text())["reward"]["checkpoint"]).exists()
    p = subprocess.run(
        [
            str(BIN / "drs-eval"),
            str(REPO / RECORD),
            "--split",
            "test",
            "--episodes",
            "2",
            "--out",
            str(tmp_path / "eval.json"),
        ],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=tmp_path,
    )
    assert p.returncode == 0, p.stderr[-2000:]
    res = json.loads((tmp_path / "eval.json").read_text())
    assert res["episodes"] == 2 and res["split"] == "test" and len(res["rows"]) == 2


def _run_dir(d: Path, phase: str, checkpoint: str | None = None):
    d.mkdir(parents=True)
    reward = {"name": "drs", **({"checkpoint": checkpoint} if checkpoint else {})}
    (d / "config.yaml").write_text(
        yaml.safe_dump(
            {
                "phase": phase,
                "seed": 0,
                "total_frames": 1000,
                "reward": reward,
                "env": {"split": "test" if phase == "reuse" else "train"},
            }
        )
    )
    (d / "train.csv").write_text("step,success_rate\n1000,0.5\n")
    (d / "eval.csv").write_text("step,episodes,success_rate\n1000,10,0.5\n")
    (d / "summary.json").write_text(json.dumps({"frames": 1000, "interrupted": False}))
    if phase == "learn":
        (d / "checkpoints").mkdir()
        (d / "checkpoints" / "reward.pt").write_bytes(b"learned " + d.name.encode())
        (d / "checkpoints" / "policy.pt").write_bytes(b"policy")


def test_report_pins_the_reward_a_reuse_run_reused_in_its_record(tmp_path, monkeypatch, capsys):
    """A reuse run listed before the phase-1 run it reused; one reusing a committed reward; one whose reward is nowhere."""
    from drs_torchrl.tools.study import main

    monkeypatch.chdir(tmp_path)  # the repository root, where studies run: the pins are relative to it
    committed = tmp_path / "results" / "shared" / "reward.pt"
    committed.parent.mkdir(parents=True)
    committed.write_bytes(b"a committed reward")
    spec = {
        "root": "runs/s",
        "app": "reuse",
        "record": "results/s",
        "runs": [
            {"name": "drs_s0", "args": ["reward.checkpoint=<reward:learn_s0>"], "needs": ["learn_s0"]},
            {"name": "shared_s0", "args": ["reward.checkpoint=results/shared/reward.pt"]},
            {"name": "gone_s0", "args": ["reward.checkpoint=/nowhere/reward.pt"]},
            {"name": "learn_s0", "app": "learn", "args": []},
        ],
    }
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(spec))
    _run_dir(tmp_path / "runs/s/learn_s0", "learn")
    _run_dir(tmp_path / "runs/s/drs_s0", "reuse", str(tmp_path / "runs/s/learn_s0/checkpoints/reward.pt"))
    _run_dir(tmp_path / "runs/s/shared_s0", "reuse", "results/shared/reward.pt")
    _run_dir(tmp_path / "runs/s/gone_s0", "reuse", "/nowhere/reward.pt")
    assert main(["study.yaml", "--report", "results/s"]) == 0
    files = tmp_path / "results/s/run_files"
    pin = json.loads((files / "drs_s0" / REWARD_PIN).read_text())
    assert pin == {
        "checkpoint": "results/s/run_files/learn_s0/reward.pt",
        "ran_with": "runs/s/learn_s0/checkpoints/reward.pt",
        "sha256": sha256_file(files / "learn_s0" / "reward.pt"),
    }
    assert (files / "drs_s0" / "config.yaml").read_text().count(
        "runs/s/learn_s0/checkpoints/reward.pt"
    ) == 1  # as it ran
    assert pinned_reward(files / "drs_s0") == (files / "learn_s0" / "reward.pt").resolve()
    assert json.loads((files / "shared_s0" / REWARD_PIN).read_text())["checkpoint"] == "results/shared/reward.pt"
    assert not (files / "gone_s0" / REWARD_PIN).exists() and not (files / "learn_s0" / REWARD_PIN).exists()
    assert "gone_s0 reused /nowhere/reward.pt, which the record does not hold" in capsys.readouterr().err
    # from another working directory the record still finds its reward (the pin is looked up from the record upwards)
    monkeypatch.chdir(files)
    assert pinned_reward(files / "drs_s0") == (files / "learn_s0" / "reward.pt").resolve()
