"""The pre-registered fine-tuning study (results/finetune/PREREGISTRATION.md): its budget rule (make_studies.py) and
its decision rule (decide.py), applied to made-up records whose verdicts are known."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
FT = REPO / "results" / "finetune"
REWARDS = ("drs", "semi_sparse", "dense", "sparse")


def module(name: str):
    spec = importlib.util.spec_from_file_location(f"ft_{name}", FT / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_budget_rule():
    ms = module("make_studies")
    assert ms.threshold(0.55) == 0.75 and ms.threshold(0.85) == 1.0
    assert ms.budget([30016, 50048]) == 80_000  # 1.5 x 50048 = 75072, rounded up to 10k
    assert ms.budget([20032, 10048]) == 40_000
    assert ms.budget([70016, 80000]) == 120_000  # the cap
    assert ms.budget([10048, None]) == 120_000  # a seed that never passes: the cap


def test_the_generated_study_files_are_valid_studies(tmp_path):
    from drs_torchrl.tools.study import load_study

    ms = module("make_studies")
    f = tmp_path / "study.yaml"
    f.write_text(ms.study_yaml("stack_cube", {"learn_s0": 80_000, "learn_s1": 120_000}))
    root, runs = load_study(f)
    assert len(runs) == 24 and str(root) == "runs/finetune_stack_cube"
    by_name = {r.name: r.args for r in runs}
    drs = by_name["learn_s1-drs_s2"]
    assert (
        "total_frames=120000" in drs
        and "seed=2" in drs
        and "init_from=results/recipe/stack_cube/run_files/learn_s1" in drs
    )
    assert "reward.checkpoint=results/recipe/stack_cube/run_files/learn_s1/reward.pt" in drs
    assert not any(a.startswith("reward.checkpoint") for a in by_name["learn_s0-dense_s0"])


STEPS = list(range(10_000, 80_001, 10_000))


def record(tmp_path: Path, finals: dict[str, float], z=(0.5, 0.5), unfinished: str | None = None) -> Path:
    """A family 'fam' with two policies (zero-shot ``z``), budget 80k; every run of arm a ends at finals[a]
    (rising linearly from z_p); one seed of dense at finals['dense'] - 0.1 (a spread)."""
    folder = tmp_path / "fam"
    (tmp_path / "zero_shot").mkdir()
    runs = []
    for p, zp in zip(("learn_s0", "learn_s1"), z):
        (tmp_path / "zero_shot" / f"fam-{p}.json").write_text(json.dumps({"success_once": zp}))
        for r in REWARDS:
            for s in range(3):
                name = f"{p}-{r}_s{s}"
                runs.append({"name": name, "args": ["total_frames=80000", f"seed={s}"]})
                d = folder / "run_files" / name
                d.mkdir(parents=True)
                final = finals[r] - (0.1 if (r == "dense" and s == 2) else 0.0)
                rows = ["step,episodes,success_rate"] + [f"{t},20,{zp + (final - zp) * t / 80_000:.4f}" for t in STEPS]
                (d / "eval.csv").write_text("\n".join(rows) + "\n")
                done = name != unfinished
                (d / "summary.json").write_text(
                    json.dumps({"frames": 80_000 if done else 40_000, "interrupted": not done})
                )
    (folder / "study.yaml").write_text(yaml.safe_dump({"app": "reuse", "runs": runs}))
    return folder


def decide(folder: Path) -> str:
    out = subprocess.run(
        [sys.executable, str(FT / "decide.py"), str(folder)], capture_output=True, text=True, check=True
    )
    assert (folder / "decision.md").read_text() == out.stdout
    return out.stdout


def test_drs_beats_semi_sparse_and_matches_dense_the_claim_holds(tmp_path):
    text = decide(record(tmp_path, {"drs": 0.9, "semi_sparse": 0.6, "dense": 0.9, "sparse": 0.5}))
    assert "DrS vs semi_sparse: **DrS beats semi_sparse** (final +0.30" in text
    assert "DrS vs dense: **no difference** (final +0.03" in text  # dense: 0.9, 0.9, 0.8 per policy
    assert "DrS vs sparse: **DrS beats sparse**" in text
    assert "on fam: **holds**" in text and "All runs finished" in text
    assert "| dense | 6 of 6 | 0.87 |" in text and "| 0.05 |" in text  # the population std of 0.9, 0.9, 0.8 (x2)


def test_dense_beats_drs_the_claim_fails(tmp_path):
    text = decide(record(tmp_path, {"drs": 0.6, "semi_sparse": 0.3, "dense": 1.0, "sparse": 0.5}))
    assert "DrS vs dense: **dense beats DrS**" in text and "DrS vs semi_sparse: **DrS beats semi_sparse**" in text
    assert "on fam: **fails**" in text


def test_no_arm_moves_the_policies_no_signal(tmp_path):
    text = decide(record(tmp_path, {"drs": 0.6, "semi_sparse": 0.3, "dense": 0.65, "sparse": 0.5}))
    assert text.count("**no signal**") == 3 and "on fam: **not shown**" in text


def test_an_unfinished_run_leaves_its_comparisons_undecided(tmp_path):
    text = decide(
        record(tmp_path, {"drs": 0.9, "semi_sparse": 0.6, "dense": 0.9, "sparse": 0.5}, unfinished="learn_s1-dense_s1")
    )
    assert "Provisional: 1 of 24 runs not finished" in text
    assert "DrS vs dense: not decidable yet" in text and "DrS vs semi_sparse: **DrS beats semi_sparse**" in text
    assert "not decidable yet" in text.split("The paper's claim")[1]


def test_auc_starts_from_the_zero_shot_success(tmp_path):
    dec = module("decide")
    folder = record(tmp_path, {"drs": 0.5, "semi_sparse": 0.5, "dense": 0.5, "sparse": 0.5}, z=(0.5, 0.5))
    m = dec.run_metrics(folder / "run_files" / "learn_s0-drs_s0", 80_000, 0.5)
    assert abs(m["auc"] - 0.5) < 1e-6 and m["final"] == 0.5 and m["first_past"] is None
