#!/usr/bin/env python
"""The agent-selection study of issue 64 (results/selection/PREREGISTRATION.md): speeds, budgets, study files and the
pre-registered rules. Written before any run of the study.

    .venv/bin/python results/selection/selection.py speed RUN_DIR...   # step 0's runs -> speed.json
    .venv/bin/python results/selection/selection.py budgets            # speed.json -> round1/study.yaml
    .venv/bin/python results/selection/selection.py round1             # round 1's record -> decision.md (+ round 2)
    .venv/bin/python results/selection/selection.py round2             # round 2's record -> decision.md
"""

from __future__ import annotations

import json
import math
import platform
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

HERE = Path(__file__).resolve().parent
CONTROL = "sac_cpu"
CANDIDATES = ("sac_cpu", "sac_ln", "sac_ln_utd1_b128", "crossq", "sac_ens10_ln")
SEEDS = (0, 1, 2)
TARGET, STREAK = 0.8, 2
SPEED_AFTER = 6000  # step 0: env steps/s of the train.csv rows past this many env steps
MIN_BUDGET, ROUND_TO = 40_000, 10_000
FINALIST_FACTOR = 0.75  # round 1: the finalist needs M_C <= 0.75 M_control
AUC_TOLERANCE = 0.05  # round 2: turn_valve AUC non-inferiority margin
TOL = 1e-9
COMMON = ["env.split=test", "algo.precision=fp32", "eval.episodes=10", "eval.episode_seed=5000",
          f"eval.stop_at_success={TARGET}", f"eval.stop_streak={STREAK}", "checkpoint_interval=20000",
          "logger.progress_bar=false", "algo.collector._target_=torchrl.collectors.Collector"]  # fmt: skip
# round 1's arm, then round 2's two: (env, reward args, the control's budget, evaluation interval)
ARMS = {
    "pick_dense": ("pick_cube", ["reward=dense"], 160_000, 10_000),
    "pick_drs5": (
        "pick_cube",
        [
            "reward=drs",
            "+ablation=placed_5cm",
            "reward.checkpoint=results/reuse/pick_cube/run_files/learn-placed_5cm_s0/reward.pt",
        ],
        300_000,
        10_000,
    ),  # fmt: skip
    "valve_drs": (
        "turn_valve",
        ["reward=drs", "reward.checkpoint=results/families/turn_valve_reuse/reward_levels024_121k.pt"],
        300_000,
        20_000,
    ),
}
ROUNDS = {"round1": ("pick_dense",), "round2": ("pick_drs5", "valve_drs")}


# ------------------------------------------------------------------------------------------------ step 0: speeds
def run_speed(run_dir: Path) -> float:
    """Env steps/s of one timing run: the mean of ``train.csv``'s rows past ``SPEED_AFTER`` env steps."""
    tr = pd.read_csv(run_dir / "train.csv")
    rows = tr[tr["frames"] > SPEED_AFTER]["env_steps_per_s"].dropna()
    if rows.empty:
        raise SystemExit(f"{run_dir}: no train.csv row past {SPEED_AFTER} env steps")
    return float(rows.mean())


def speeds(run_dirs: list[Path]) -> dict:
    """``{candidate: mean env steps/s over its timing runs}`` (each run's config names its algo)."""
    per: dict[str, list[float]] = {}
    for d in run_dirs:
        algo = yaml.safe_load((d / "config.yaml").read_text())["algo"]["name"]
        per.setdefault(algo, []).append(run_speed(d))
    missing = [c for c in CANDIDATES if c not in per]
    if missing:
        raise SystemExit(f"no timing run of {missing}")
    return {c: float(np.mean(per[c])) for c in CANDIDATES} | {"_runs": per}


def budget(candidate: str, control_budget: int, v: dict) -> int:
    """Equal wall-clock budgets: the control's env steps scaled by the candidate's speed, up to 10k, at least 40k."""
    steps = control_budget * v[candidate] / v[CONTROL]
    return max(MIN_BUDGET, int(math.ceil(steps / ROUND_TO - TOL)) * ROUND_TO)


def study_file(round_name: str, candidates: list[str], v: dict) -> str:
    arms = ROUNDS[round_name]
    header = (
        f"# Pre-registered (issue 64; protocol: results/selection/PREREGISTRATION.md): {round_name} of the agent selection.\n"
        "# Written by results/selection/selection.py from speed.json"
        + (" and round 1's decision" if round_name == "round2" else "")
        + "; not edited by hand. Run (and re-run until done) from\n"
        "# the worktree pinned to the pre-registration commit:\n"
        f"#   mkdir -p runs/selection_{round_name} && nohup .venv/bin/drs-study results/selection/{round_name}/study.yaml "
        f"--jobs 2 >> runs/selection_{round_name}/study.log 2>&1 &\n"
        f"#   .venv/bin/drs-study results/selection/{round_name}/study.yaml --report results/selection/{round_name}\n"
    )
    runs = []
    for seed in SEEDS:  # seed-major: a partial study is balanced across candidates
        for arm in arms:
            env, reward, control_budget, interval = ARMS[arm]
            for c in candidates:
                name = f"{c}_s{seed}" if round_name == "round1" else f"{arm}-{c}_s{seed}"
                args = [f"env={env}", f"algo={c}", *reward, f"total_frames={budget(c, control_budget, v)}",
                        f"eval.interval={interval}", f"seed={seed}"]  # fmt: skip
                runs.append({"name": name, "args": args})
    spec = {
        "description": f"pre-registered: agent selection {round_name} ({', '.join(candidates)}), 3 seeds",
        "root": f"runs/selection_{round_name}",
        "record": f"results/selection/{round_name}",
        "app": "reuse",
        "common": COMMON,
        "runs": runs,
    }
    return header + yaml.safe_dump(spec, sort_keys=False, width=200)


# ------------------------------------------------------------------------------------------------ the metrics
def run_metrics(run_dir: Path, budget_steps: int) -> dict | None:
    """``T`` (env steps of the first of STREAK evaluations in a row >= TARGET, or the budget: censored) and the success
    AUC from (0, 0) to the budget (the last evaluation carried to it); None while the run has not finished."""
    summary = json.loads((run_dir / "summary.json").read_text())
    stopped = summary.get("stopped_at_eval_success")
    if summary.get("interrupted") or (int(summary.get("frames", 0)) < budget_steps and not stopped):
        return None
    ev = pd.read_csv(run_dir / "eval.csv").drop_duplicates("step", keep="last").sort_values("step")
    ev = ev[ev["step"] <= budget_steps + 1000]
    steps, success = ev["step"].to_numpy(float), ev["success_rate"].to_numpy(float)
    hit = success >= TARGET - TOL
    first = next((i for i in range(len(hit) - STREAK + 1) if hit[i : i + STREAK].all()), None)
    xs = np.concatenate([[0.0], steps, [float(budget_steps)]])
    ys = np.concatenate([[0.0], success, [success[-1] if len(success) else 0.0]])
    auc = float(np.sum((ys[1:] + ys[:-1]) * np.diff(xs)) / 2.0 / budget_steps)
    return {
        "T": int(steps[first]) if first is not None else int(budget_steps),
        "censored": first is None,
        "final": float(success[-1]) if len(success) else 0.0,
        "auc": auc,
        "frames": int(summary.get("frames", 0)),
    }


def budget_of(run: dict) -> int:
    return int(next(a.split("=", 1)[1] for a in reversed(run["args"]) if a.startswith("total_frames=")))


def algo_of(run: dict) -> str:
    return next(a.split("=", 1)[1] for a in run["args"] if a.startswith("algo="))


def arm_of(run: dict, round_name: str) -> str:
    return ROUNDS[round_name][0] if round_name == "round1" else run["name"].split("-", 1)[0]


def collect(folder: Path, v: dict) -> dict:
    """Per (arm, candidate): its runs' metrics, minutes, ``M``, ``solved`` and mean AUC; and the runs not finished."""
    round_name = folder.name
    study = yaml.safe_load((folder / "study.yaml").read_text())
    table: dict[tuple[str, str], dict] = {}
    pending = []
    for run in study["runs"]:
        d = folder / "run_files" / run["name"]
        m = run_metrics(d, budget_of(run)) if (d / "summary.json").is_file() else None
        key = (arm_of(run, round_name), algo_of(run))
        t = table.setdefault(key, {"runs": {}, "expected": 0})
        t["expected"] += 1
        if m is None:
            pending.append(run["name"])
            continue
        m["minutes"] = m["T"] / v[key[1]] / 60.0
        t["runs"][run["name"]] = m
    for t in table.values():
        ms = list(t["runs"].values())
        t["complete"] = len(ms) == t["expected"]
        t["M"] = float(np.mean([m["minutes"] for m in ms])) if ms else None
        t["solved"] = sum(not m["censored"] for m in ms)
        t["auc"] = float(np.mean([m["auc"] for m in ms])) if ms else None
    return {"table": table, "pending": pending, "names": [r["name"] for r in study["runs"]]}


# ------------------------------------------------------------------------------------------------ the rules
def round1_rule(table: dict) -> dict:
    """The finalist: smallest M among candidates != control with all seeds solved and M <= 0.75 M_control."""
    arm = ROUNDS["round1"][0]
    cands = sorted({c for a, c in table if a == arm})
    if not all(table[(arm, c)]["complete"] for c in cands):
        return {"final": False, "finalist": None}
    control = table[(arm, CONTROL)]["M"]
    ok = [
        c
        for c in cands
        if c != CONTROL
        and table[(arm, c)]["solved"] == table[(arm, c)]["expected"]
        and table[(arm, c)]["M"] <= FINALIST_FACTOR * control + TOL
    ]
    finalist = min(ok, key=lambda c: table[(arm, c)]["M"]) if ok else None
    return {"final": True, "finalist": finalist, "qualified": ok, "control_M": control}


def round2_rule(table: dict, finalist: str) -> dict:
    keys = [(a, c) for a in ROUNDS["round2"] for c in (finalist, CONTROL)]
    if not all(k in table and table[k]["complete"] for k in keys):
        return {"final": False, "adopt": None}
    pick_f, pick_c = table[("pick_drs5", finalist)], table[("pick_drs5", CONTROL)]
    valve_f, valve_c = table[("valve_drs", finalist)], table[("valve_drs", CONTROL)]
    i = pick_f["M"] <= pick_c["M"] + TOL and pick_f["solved"] >= pick_c["solved"]
    ii = valve_f["auc"] >= valve_c["auc"] - AUC_TOLERANCE - TOL
    return {"final": True, "adopt": bool(i and ii), "pick": i, "valve": ii}


# ------------------------------------------------------------------------------------------------ reports
def table_md(r: dict) -> list[str]:
    out = ["| run | T (env steps) | censored | minutes | final | AUC |", "|---|---|---|---|---|---|"]
    rows = {n: m for t in r["table"].values() for n, m in t["runs"].items()}
    for n in r["names"]:
        m = rows.get(n)
        out.append(
            f"| {n} | "
            + (
                f"{m['T']} | {'yes' if m['censored'] else 'no'} | {m['minutes']:.1f} | {m['final']:.2f} | {m['auc']:.3f}"
                if m
                else "not finished | | | |"
            )
            + " |"
        )
    out += ["", "| arm | candidate | runs | solved | M (minutes) | mean AUC |", "|---|---|---|---|---|---|"]
    for (arm, c), t in sorted(r["table"].items()):
        if t["runs"]:
            out.append(
                f"| {arm} | {c} | {len(t['runs'])} of {t['expected']} | {t['solved']} | {t['M']:.1f} | {t['auc']:.3f} |"
            )
    return out


def decision_md(round_name: str, r: dict, v: dict, verdict: list[str]) -> str:
    head = [
        f"# Agent selection, {round_name}: the pre-registered rule applied",
        "",
        f"Generated by `.venv/bin/python results/selection/selection.py {round_name}` from `run_files/` and "
        f"`../speed.json` ({v.get('_machine', 'machine not recorded')}). "
        + (
            "**All runs finished: the verdict is final.**"
            if not r["pending"]
            else f"**Provisional: {len(r['pending'])} of {len(r['names'])} runs not finished.**"
        ),
        "",
        "Speeds (env steps/s, step 0): " + ", ".join(f"{c} {v[c]:.1f}" for c in CANDIDATES if c in v) + ".",
        "",
    ]
    return "\n".join([*head, *table_md(r), "", *verdict]) + "\n"


def load_speeds() -> dict:
    path = HERE / "speed.json"
    if not path.is_file():
        raise SystemExit("no results/selection/speed.json yet: run results/selection/speed.sh on an idle machine")
    return json.loads(path.read_text())


def main(argv: list[str]) -> int:
    cmd = argv[0] if argv else ""
    if cmd == "speed":
        v = speeds([Path(a) for a in argv[1:]])
        v["_machine"] = f"{platform.processor() or platform.machine()}, {_cpu_model()}"
        (HERE / "speed.json").write_text(json.dumps(v, indent=2) + "\n")
        print(json.dumps({c: round(v[c], 1) for c in CANDIDATES}))
        return 0
    v = load_speeds()
    if cmd == "budgets":
        (HERE / "round1").mkdir(exist_ok=True)
        (HERE / "round1" / "study.yaml").write_text(study_file("round1", list(CANDIDATES), v))
        print("wrote results/selection/round1/study.yaml: commit it, then start it from the pinned worktree")
        return 0
    if cmd == "round1":
        r = collect(HERE / "round1", v)
        rule = round1_rule(r["table"])
        if not rule["final"]:
            verdict = ["Not decidable yet: a candidate has runs not finished."]
        elif rule["finalist"] is None:
            verdict = [
                f"**No finalist: today's default (`{CONTROL}`) is kept.** No candidate solved all seeds with "
                f"M <= {FINALIST_FACTOR} x {rule['control_M']:.1f} min; round 2 is not run."
            ]
        else:
            verdict = [
                f"**Finalist: `{rule['finalist']}`** (qualified: {', '.join(rule['qualified'])}; control M "
                f"{rule['control_M']:.1f} min). Round 2's study file: `round2/study.yaml`."
            ]
            (HERE / "round2").mkdir(exist_ok=True)
            study = HERE / "round2" / "study.yaml"
            if not study.is_file():  # written once, from the final round-1 verdict
                study.write_text(study_file("round2", [rule["finalist"], CONTROL], v))
        (HERE / "round1" / "decision.md").write_text(decision_md("round1", r, v, verdict))
        print(*verdict)
        return 0
    if cmd == "round2":
        r = collect(HERE / "round2", v)
        finalist = next(c for a, c in r["table"] if c != CONTROL)
        rule = round2_rule(r["table"], finalist)
        if not rule["final"]:
            verdict = ["Not decidable yet: an arm has runs not finished."]
        else:
            verdict = [
                f"(i) pick_cube with DrS 5 cm, M and solved no worse than `{CONTROL}`: {'yes' if rule['pick'] else 'no'}",
                f"(ii) turn_valve with DrS, AUC >= `{CONTROL}`'s - {AUC_TOLERANCE}: {'yes' if rule['valve'] else 'no'}",
                "",
                f"**`{finalist}` becomes the new default.**"
                if rule["adopt"]
                else f"**Today's default (`{CONTROL}`) is kept.**",
            ]
        (HERE / "round2" / "decision.md").write_text(decision_md("round2", r, v, verdict))
        print(*verdict, sep="\n")
        return 0
    print(__doc__)
    return 2


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown CPU"


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
