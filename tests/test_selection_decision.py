"""The pre-registered agent selection (results/selection/PREREGISTRATION.md): its budgets, study files, metrics and
both rounds' rules, applied to made-up records whose verdicts are known."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
SEL = REPO / "results" / "selection"
SPEEDS = {"sac_cpu": 60.0, "sac_ln": 54.0, "sac_ln_utd1_b128": 45.0, "crossq": 20.0, "sac_ens10_ln": 18.0}


@pytest.fixture(scope="module")
def sel():
    spec = importlib.util.spec_from_file_location("selection", SEL / "selection.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_budgets_give_every_candidate_the_controls_minutes(sel):
    assert sel.budget("sac_cpu", 160_000, SPEEDS) == 160_000
    assert sel.budget("sac_ln", 160_000, SPEEDS) == 150_000  # 144k rounded up to 10k
    assert sel.budget("crossq", 160_000, SPEEDS) == 60_000  # 53.3k
    assert sel.budget("crossq", 100_000, SPEEDS) == 40_000  # 33.3k: at least 40k
    assert sel.budget("sac_cpu", 160_000, {**SPEEDS, "sac_cpu": 20.0}) == 160_000


def test_the_study_files_are_valid_studies_with_the_protocols_settings(sel, tmp_path):
    from drs_torchrl.tools.study import load_study

    for round_name, cands, n in (("round1", list(sel.CANDIDATES), 15), ("round2", ["crossq", "sac_cpu"], 12)):
        f = tmp_path / round_name / "study.yaml"
        f.parent.mkdir()
        f.write_text(sel.study_file(round_name, cands, SPEEDS))
        root, runs = load_study(f)
        assert len(runs) == n and {r.app for r in runs} == {"reuse"} and str(root) == f"runs/selection_{round_name}"
        spec = yaml.safe_load(f.read_text())
        assert "eval.stop_at_success=0.8" in spec["common"] and "algo.precision=fp32" in spec["common"]
        assert "eval.episode_seed=5000" in spec["common"] and "env.split=test" in spec["common"]
        first = spec["runs"][: len(cands) * (1 if round_name == "round1" else 2)]
        assert all("seed=0" in r["args"] for r in first)  # seed-major
    r1 = {r["name"]: r for r in yaml.safe_load((tmp_path / "round1" / "study.yaml").read_text())["runs"]}
    assert "total_frames=60000" in r1["crossq_s2"]["args"] and "total_frames=160000" in r1["sac_cpu_s0"]["args"]
    r2 = {r["name"]: r for r in yaml.safe_load((tmp_path / "round2" / "study.yaml").read_text())["runs"]}
    assert "eval.interval=20000" in r2["valve_drs-sac_cpu_s1"]["args"]
    assert "+ablation=placed_5cm" in r2["pick_drs5-crossq_s0"]["args"]
    assert "total_frames=100000" in r2["pick_drs5-crossq_s0"]["args"]  # 300k x 20 / 60


def fake_run(folder: Path, name: str, evals: list[float], interval: int, stopped: bool = False, frames=None):
    d = folder / "run_files" / name
    d.mkdir(parents=True)
    steps = [interval * (i + 1) for i in range(len(evals))]
    lines = ["step,episodes,success_rate"] + [f"{s},10,{e}" for s, e in zip(steps, evals)]
    (d / "eval.csv").write_text("\n".join(lines) + "\n")
    summary = {"frames": frames if frames is not None else steps[-1], "interrupted": False}
    if stopped:
        summary["stopped_at_eval_success"] = {"frames": steps[-1]}
    (d / "summary.json").write_text(json.dumps(summary))


def test_the_metrics_of_a_run(sel, tmp_path):
    # 0.8, then 0.6 (no streak), then 0.9, 0.8: T is the first of the two in a row, at 30k; stopped at 40k
    fake_run(tmp_path, "a", [0.8, 0.6, 0.9, 0.8], 10_000, stopped=True)
    m = sel.run_metrics(tmp_path / "run_files" / "a", 100_000)
    assert m["T"] == 30_000 and not m["censored"] and m["final"] == 0.8
    # AUC: trapezoids (0,0)-(10k,.8)-(20k,.6)-(30k,.9)-(40k,.8), then 0.8 carried to 100k
    expected = (0.4 * 10 + 0.7 * 10 + 0.75 * 10 + 0.85 * 10 + 0.8 * 60) / 100
    assert m["auc"] == pytest.approx(expected)
    fake_run(tmp_path, "b", [0.1, 0.9, 0.2, 0.3], 10_000, frames=40_000)  # budget reached, never two in a row
    m = sel.run_metrics(tmp_path / "run_files" / "b", 40_000)
    assert m["T"] == 40_000 and m["censored"]
    fake_run(tmp_path, "c", [0.1, 0.2], 10_000, frames=20_000)  # still running
    assert sel.run_metrics(tmp_path / "run_files" / "c", 40_000) is None


def write_round(sel, tmp_path, round_name, cands, outcomes):
    """``outcomes[(arm, candidate)]`` = the step index (1-based, in evaluations) at which each seed's streak starts,
    None for a seed that never reaches it (censored at its budget)."""
    folder = tmp_path / round_name
    folder.mkdir()
    (folder / "study.yaml").write_text(sel.study_file(round_name, cands, SPEEDS))
    runs = yaml.safe_load((folder / "study.yaml").read_text())["runs"]
    for run in runs:
        arm = sel.arm_of(run, round_name)
        c, seed = sel.algo_of(run), int(run["name"].rsplit("_s", 1)[1])
        interval = sel.ARMS[arm][3]
        budget = sel.budget_of(run)
        at = outcomes[(arm, c)][seed]
        if at is None:
            n = budget // interval
            fake_run(folder, run["name"], [0.3] * n, interval, frames=budget)
        else:
            fake_run(folder, run["name"], [0.1] * (at - 1) + [0.9, 0.9], interval, stopped=True)
    return folder


def test_round_1_picks_the_candidate_fastest_in_minutes_not_in_env_steps(sel, tmp_path):
    # in env steps crossq solves first (20k), but at a third of the speed its minutes (16.7) exceed sac_ln's
    # (50k / 54 env steps/s = 15.4); the control: 100k / 60 = 27.8 min, so both are under 0.75 x 27.8 = 20.8
    out = {
        ("pick_dense", "sac_cpu"): [10, 10, 10],
        ("pick_dense", "sac_ln"): [5, 5, 5],
        ("pick_dense", "sac_ln_utd1_b128"): [9, 9, 9],  # 33 min: not fast enough
        ("pick_dense", "crossq"): [2, 2, 2],
        ("pick_dense", "sac_ens10_ln"): [2, 2, None],  # a censored seed: not a finalist
    }
    r = sel.collect(write_round(sel, tmp_path, "round1", list(sel.CANDIDATES), out), SPEEDS)
    rule = sel.round1_rule(r["table"])
    assert rule["final"] and rule["finalist"] == "sac_ln"
    assert sorted(rule["qualified"]) == ["crossq", "sac_ln"]
    assert r["table"][("pick_dense", "sac_ln")]["M"] == pytest.approx(50_000 / 54 / 60)


def test_round_1_keeps_the_default_when_no_candidate_is_a_quarter_faster(sel, tmp_path):
    out = {("pick_dense", c): [10, 10, 10] for c in sel.CANDIDATES}
    out[("pick_dense", "sac_ln")] = [8, 8, 8]  # 24.7 min against 27.8: 0.89 of the control's
    r = sel.collect(write_round(sel, tmp_path, "round1", list(sel.CANDIDATES), out), SPEEDS)
    assert sel.round1_rule(r["table"]) == {
        "final": True,
        "finalist": None,
        "qualified": [],
        "control_M": pytest.approx(100_000 / 60 / 60),
    }


def test_round_1_waits_for_every_run(sel, tmp_path):
    out = {("pick_dense", c): [10, 10, 10] for c in sel.CANDIDATES}
    folder = write_round(sel, tmp_path, "round1", list(sel.CANDIDATES), out)
    (folder / "run_files" / "crossq_s2" / "summary.json").write_text(json.dumps({"frames": 100, "interrupted": True}))
    r = sel.collect(folder, SPEEDS)
    assert r["pending"] == ["crossq_s2"] and sel.round1_rule(r["table"])["final"] is False


@pytest.mark.parametrize(
    ("pick_f", "valve_f_censored_auc_low", "adopt"),
    [([5, 5, 5], False, True), ([5, 5, None], False, False), ([5, 5, 5], True, False)],
)
def test_round_2_adopts_only_when_both_arms_hold(sel, tmp_path, pick_f, valve_f_censored_auc_low, adopt):
    out = {
        ("pick_drs5", "sac_cpu"): [20, 20, 20],
        ("pick_drs5", "sac_ln"): pick_f,
        ("valve_drs", "sac_cpu"): [None, None, None],
        ("valve_drs", "sac_ln"): [None, None, None],
    }
    folder = write_round(sel, tmp_path, "round2", ["sac_ln", "sac_cpu"], out)
    if valve_f_censored_auc_low:  # the finalist's turn_valve runs at success 0.0 throughout: AUC 0 against 0.3
        for s in range(3):
            d = folder / "run_files" / f"valve_drs-sac_ln_s{s}"
            lines = (d / "eval.csv").read_text().splitlines()
            (d / "eval.csv").write_text(
                "\n".join([lines[0], *(ln.rsplit(",", 1)[0] + ",0.0" for ln in lines[1:])]) + "\n"
            )
    r = sel.collect(folder, SPEEDS)
    rule = sel.round2_rule(r["table"], "sac_ln")
    assert rule["final"] and rule["adopt"] is adopt


def test_step_0_speeds_are_the_mean_env_steps_per_s_past_6000_of_each_candidates_runs(sel, tmp_path):
    dirs = []
    for i, (algo, rates) in enumerate(
        [(c, [900.0, 50.0, 60.0]) for c in sel.CANDIDATES] + [("crossq", [900.0, 10.0, 30.0])]
    ):
        d = tmp_path / f"r{i}"
        d.mkdir()
        (d / "config.yaml").write_text(f"algo:\n  name: {algo}\n  updater:\n    gamma: ${{algo.gamma}}\n")
        rows = ["step,frames,env_steps_per_s"] + [f"{f},{f},{r}" for f, r in zip((5000, 7000, 8000), rates)]
        (d / "train.csv").write_text("\n".join(rows) + "\n")  # the 5000 row (random actions) is left out
        dirs.append(d)
    v = sel.speeds(dirs)
    assert v["sac_cpu"] == 55.0 and v["crossq"] == (55.0 + 20.0) / 2
    assert v["_runs"]["crossq"] == [55.0, 20.0]
    with pytest.raises(SystemExit, match="no timing run of"):
        sel.speeds(dirs[:2])
