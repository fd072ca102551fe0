#!/usr/bin/env python
"""Apply the pre-registered decision rule of the fine-tuning study (results/finetune/PREREGISTRATION.md) to a
family's committed stage-B record. Written before any stage-B run.

    .venv/bin/python results/finetune/decide.py results/finetune/stack_cube      # -> .../decision.md
    .venv/bin/python results/finetune/decide.py --readme results/finetune/stack_cube results/finetune/place_sphere

Per run (run_files/<policy>-<reward>_s<seed>/eval.csv, budget B_p = its study entry's total_frames): final = success
at the last evaluation, AUC = trapezoids from step 0 (the policy's zero-shot success z_p, zero_shot/) to B_p divided by
B_p, first past z_p + 0.2. Arms pool the family's two policies x 3 seeds. Until every run has finished the verdicts
are marked provisional (the rule is applied only to complete arms).
"""

from __future__ import annotations

import json
import statistics
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

HERE = Path(__file__).resolve().parent
MARGIN, LIFT = 0.2, 0.2
TOLERANCE = 1e-9  # successes are multiples of 1/20; their means floats
BASELINES = ("semi_sparse", "dense", "sparse")
LABELS = {"drs": "DrS (own reward)", "semi_sparse": "semi-sparse", "dense": "dense", "sparse": "sparse"}


def zero_shot(folder: Path, policy: str) -> float:
    return float(json.loads((folder.parent / "zero_shot" / f"{folder.name}-{policy}.json").read_text())["success_once"])


def parse(name: str) -> tuple[str, str, int]:
    """``learn_s0-semi_sparse_s2`` -> (policy, reward, seed)."""
    policy, rest = name.split("-", 1)
    reward, seed = rest.rsplit("_s", 1)
    return policy, reward, int(seed)


def budget_of(run: dict) -> int:
    return int(next(a.split("=", 1)[1] for a in reversed(run["args"]) if a.startswith("total_frames=")))


def run_metrics(run_dir: Path, budget: int, z: float) -> dict | None:
    summary = json.loads((run_dir / "summary.json").read_text())
    if summary.get("interrupted") or int(summary.get("frames", 0)) < budget:
        return None  # not finished
    ev = pd.read_csv(run_dir / "eval.csv").drop_duplicates("step", keep="last").sort_values("step")
    ev = ev[ev["step"] <= budget + 1000]
    steps = np.concatenate([[0.0], ev["step"].to_numpy(float)])
    success = np.concatenate([[z], ev["success_rate"].to_numpy(float)])
    past = steps[1:][success[1:] >= min(1.0, z + LIFT) - TOLERANCE]
    auc = float(np.sum((success[1:] + success[:-1]) * np.diff(steps)) / 2.0 / steps[-1])
    return {"final": float(success[-1]), "auc": auc, "first_past": int(past[0]) if past.size else None}


def decide(folder: Path) -> dict:
    study = yaml.safe_load((folder / "study.yaml").read_text())
    runs = {r["name"]: r for r in study["runs"]}
    policies = sorted({parse(n)[0] for n in runs})
    z = {p: zero_shot(folder, p) for p in policies}
    rows, pending = {}, []
    for name, run in runs.items():
        d = folder / "run_files" / name
        p = parse(name)[0]
        m = run_metrics(d, budget_of(run), z[p]) if (d / "summary.json").is_file() else None
        (pending.append(name) if m is None else rows.__setitem__(name, m))
    expected = {a: sum(parse(n)[1] == a for n in runs) for a in LABELS}
    arms = {a: [rows[n] for n in runs if n in rows and parse(n)[1] == a] for a in LABELS}
    complete = {a for a in LABELS if expected[a] and len(arms[a]) == expected[a]}
    means = {a: {k: float(np.mean([m[k] for m in arms[a]])) for k in ("final", "auc")} for a in LABELS if arms[a]}
    spread = {a: float(statistics.pstdev([m["final"] for m in arms[a]])) for a in LABELS if arms[a]}
    mean_z = float(np.mean(list(z.values())))
    # no signal: no arm's mean final reaches the family's mean zero-shot success + 0.2 (decidable once all are in)
    all_in = complete == {a for a in LABELS if expected[a]}
    no_signal = all_in and max(means[a]["final"] for a in complete) < mean_z + LIFT - TOLERANCE
    versus = {}
    for x in BASELINES:
        if "drs" not in complete or x not in complete:
            versus[x] = None
            continue
        d_final, d_auc = means["drs"]["final"] - means[x]["final"], means["drs"]["auc"] - means[x]["auc"]
        verdict = (
            "no signal"
            if no_signal
            else "DrS beats " + x
            if d_final >= MARGIN - TOLERANCE and d_auc > 0
            else x + " beats DrS"
            if -d_final >= MARGIN - TOLERANCE and d_auc < 0
            else "no difference"
        )
        versus[x] = {"verdict": verdict, "d_final": d_final, "d_auc": d_auc}
    claim = None
    if versus["semi_sparse"] and versus["dense"] and all_in:
        v_semi, v_dense = versus["semi_sparse"]["verdict"], versus["dense"]["verdict"]
        claim = (
            "fails"
            if v_semi == "semi_sparse beats DrS" or v_dense == "dense beats DrS"
            else "holds"
            if v_semi == "DrS beats semi_sparse"
            else "not shown"
        )
    return {
        "names": list(runs),
        "rows": rows,
        "pending": pending,
        "z": z,
        "mean_z": mean_z,
        "budgets": {p: budget_of(next(r for n, r in runs.items() if parse(n)[0] == p)) for p in policies},
        "arms": arms,
        "expected": expected,
        "means": means,
        "spread": spread,
        "versus": versus,
        "no_signal": no_signal,
        "claim": claim,
    }


def per_policy_lines(r: dict) -> list[str]:
    out = ["| policy | z_p | budget | " + " | ".join(LABELS[a] for a in LABELS) + " |", "|---|---|---|---|---|---|---|"]
    for p, z in r["z"].items():
        cells = []
        for a in LABELS:
            finals = [m["final"] for n, m in r["rows"].items() if parse(n)[0] == p and parse(n)[1] == a]
            cells.append(f"{np.mean(finals):.2f} ({len(finals)} runs)" if finals else "-")
        out.append(f"| {p} | {z:.2f} | {r['budgets'][p]} | " + " | ".join(cells) + " |")
    return out


def decision_md(folder: Path, r: dict) -> str:
    out = [
        f"# {folder.name}: the pre-registered fine-tuning rule applied",
        "",
        f"Generated by `.venv/bin/python results/finetune/decide.py {folder}` from `run_files/` and `zero_shot/`. "
        + (
            "**All runs finished: the verdicts are final.**"
            if not r["pending"]
            else f"**Provisional: {len(r['pending'])} of {len(r['names'])} runs not finished.**"
        ),
        "",
        "| run | final success | AUC (from z_p at 0) | first eval >= z_p + 0.2 |",
        "|---|---|---|---|",
    ]
    for n in r["names"]:
        m = r["rows"].get(n)
        out.append(
            f"| {n} | "
            + (f"{m['final']:.2f} | {m['auc']:.3f} | {m['first_past'] or 'never'}" if m else "not finished | |")
            + " |"
        )
    out += ["", "| arm | runs | mean final | mean AUC | population std of final |", "|---|---|---|---|---|"]
    for a in LABELS:
        if r["arms"][a]:
            m = r["means"][a]
            out.append(
                f"| {LABELS[a]} | {len(r['arms'][a])} of {r['expected'][a]} | {m['final']:.2f} | {m['auc']:.3f} | "
                f"{r['spread'][a]:.2f} |"
            )
    out += ["", "Per policy (mean final; beside the rule, not part of it):", "", *per_policy_lines(r), ""]
    out += [
        f"Zero-shot success: {', '.join(f'{p} {z:.2f}' for p, z in r['z'].items())} (mean {r['mean_z']:.2f}).",
        "",
        "Rule (PREREGISTRATION.md): DrS beats X if mean final(DrS) - mean final(X) >= 0.2 and mean AUC(DrS) > mean "
        "AUC(X); X beats DrS the other way round; otherwise no difference; every comparison reads 'no signal' if no "
        "arm's mean final reaches the mean zero-shot success + 0.2.",
        "",
    ]
    for x, v in r["versus"].items():
        out.append(
            f"- DrS vs {x}: not decidable yet (an arm is incomplete)"
            if v is None
            else f"- DrS vs {x}: **{v['verdict']}** (final {v['d_final']:+.2f}, AUC {v['d_auc']:+.3f})"
        )
    out.append(
        f"- The paper's claim (H1: DrS beats semi-sparse; H2: dense does not beat DrS) on {folder.name}: "
        + (f"**{r['claim']}**" if r["claim"] else "not decidable yet")
    )
    return "\n".join(out) + "\n"


def claims_columns(folders: list[Path]) -> str:
    """The README claims table's rows for this study: one column per family."""
    results = [decide(f) for f in folders]
    lines = [
        "| pre-registered claim (`results/finetune/`) | " + " | ".join(f"`{f.name}`" for f in folders) + " |",
        "|---|" + "---|" * len(folders),
    ]

    def arm(r, a):
        n, of = len(r["arms"][a]), r["expected"][a]
        if not n:
            return f"no run finished (0 of {of})"
        m = r["means"][a]
        return f"{m['final']:.2f} [{m['auc']:.3f}]" + ("" if n == of else f" ({n} of {of} so far)")

    lines.append("| zero-shot (the policies untouched) | " + " | ".join(f"{r['mean_z']:.2f}" for r in results) + " |")
    for a in LABELS:
        lines.append(f"| fine-tuned with {LABELS[a]} | " + " | ".join(arm(r, a) for r in results) + " |")
    lines.append(
        "| the paper's claim (DrS beats semi-sparse; dense does not beat DrS) | "
        + " | ".join(f"**{r['claim']}**" if r["claim"] else "not decidable yet" for r in results)
        + " |"
    )
    return "\n".join(lines) + "\n"


def main(argv: list[str]) -> int:
    if argv[:1] == ["--readme"]:
        print(claims_columns([Path(f) for f in argv[1:]]), end="")
        return 0
    folder = Path(argv[0])
    text = decision_md(folder, decide(folder))
    (folder / "decision.md").write_text(text)
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
