#!/usr/bin/env python
"""Apply the pre-registered decision rule (results/recipe/PREREGISTRATION.md) to a family's committed record.

    .venv/bin/python results/recipe/decide.py results/recipe/stack_cube    # -> results/recipe/stack_cube/decision.md
    .venv/bin/python results/recipe/decide.py --readme results/recipe/stack_cube results/recipe/place_sphere
                                                    # the README claims table's pre-registered columns

Per run (run_files/<run>/eval.csv): final = success at the last evaluation, AUC = trapezoids from the first
evaluation to 300k divided by the width, first past 0.5 = the first evaluation step with success >= 0.5.
DrS = the drs-learn0_* and drs-learn1_* runs pooled; each baseline = its 3 runs. Until every run of the study
has finished, the verdicts are marked provisional (the rule is applied only to complete arms).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "src"))
from drs_torchrl.tools.comparison import success_auc  # noqa: E402

HORIZON, MARGIN, WORKS_AT = 300_000, 0.2, 0.5
# successes are multiples of 1/20 and their means floats: a difference of exactly 0.2 may compute as 0.19999999999999998
TOLERANCE = 1e-9
BASELINES = ("sparse", "semi_sparse", "dense")
NO_SIGNAL = (
    f"neither arm's mean final reaches {MARGIN}, the rule's margin, so this 'no difference' is an absence of signal at "
    "this budget, not evidence that the rewards are equal (a note beside the rule, not part of it)"
)


def run_metrics(run_dir: Path) -> dict | None:
    summary = json.loads((run_dir / "summary.json").read_text())
    if summary.get("interrupted") or summary.get("frames", 0) < HORIZON:
        return None  # not finished
    ev = pd.read_csv(run_dir / "eval.csv").drop_duplicates("step", keep="last").sort_values("step")
    steps, success = ev["step"].to_numpy(float), ev["success_rate"].to_numpy(float)
    past = steps[success >= WORKS_AT]
    return {
        "final": float(success[-1]),
        "auc": success_auc(steps, success, HORIZON + 1000),
        "first_past_half": int(past[0]) if past.size else None,
        "episodes": int(ev["episodes"].iloc[-1]),
    }


def arm_of(name: str) -> str:
    return "drs" if name.startswith("drs-") else name.rsplit("_s", 1)[0]


def decide(folder: Path) -> dict:
    """The rule on ``folder``'s record: per-run metrics, arms, and each verdict (None: not decidable yet)."""
    study = yaml.safe_load((folder / "study.yaml").read_text())
    names = [r["name"] for r in study["runs"] if r.get("app", study.get("app")) == "reuse"]
    rows, pending = {}, []
    for n in names:
        d = folder / "run_files" / n
        m = run_metrics(d) if (d / "summary.json").is_file() else None
        (pending.append(n) if m is None else rows.__setitem__(n, m))
    arms: dict[str, list[dict]] = {}
    for n, m in rows.items():
        arms.setdefault(arm_of(n), []).append(m)
    expected = {a: sum(arm_of(n) == a for n in names) for a in {arm_of(n) for n in names}}
    complete = {a for a in expected if len(arms.get(a, [])) == expected[a]}
    means = {a: {k: float(np.mean([m[k] for m in arms[a]])) for k in ("final", "auc")} for a in arms}
    versus = {}
    for x in BASELINES:
        if "drs" not in complete or x not in complete:
            versus[x] = None
            continue
        d_final, d_auc = means["drs"]["final"] - means[x]["final"], means["drs"]["auc"] - means[x]["auc"]
        verdict = (
            "DrS beats " + x
            if d_final >= MARGIN - TOLERANCE and d_auc > 0
            else x + " beats DrS"
            if -d_final >= MARGIN - TOLERANCE and d_auc < 0
            else "no difference"
        )
        # reported beside the verdict, not part of the rule: with both means under the margin no arm could show one
        no_signal = max(means["drs"]["final"], means[x]["final"]) < MARGIN - TOLERANCE
        versus[x] = {"verdict": verdict, "d_final": d_final, "d_auc": d_auc, "no_signal": no_signal}
    recipe = None
    if "drs" in complete:
        by_reward = {r: [rows[n]["final"] >= WORKS_AT for n in rows if n.startswith(f"drs-learn{r}_")] for r in (0, 1)}
        hits = sum(sum(v) for v in by_reward.values())
        works = hits >= 4 and all(sum(v) >= 2 for v in by_reward.values())
        recipe = {
            "verdict": "works" if works else "works partly" if hits else "fails",
            "hits": hits,
            "per_reward": (sum(by_reward[0]), sum(by_reward[1])),
            "lopsided": hits >= 4 and not works,
        }
    return {
        "names": names,
        "rows": rows,
        "pending": pending,
        "arms": arms,
        "expected": expected,
        "means": means,
        "versus": versus,
        "recipe": recipe,
    }


def decision_md(folder: Path, r: dict) -> str:
    names, rows, pending, arms, expected, means = (
        r["names"],
        r["rows"],
        r["pending"],
        r["arms"],
        r["expected"],
        r["means"],
    )
    out = [
        f"# {folder.name}: the pre-registered decision rule applied",
        "",
        f"Generated by `.venv/bin/python results/recipe/decide.py {folder}` from `run_files/`. "
        + (
            "**All runs finished: the verdicts are final.**"
            if not pending
            else f"**Provisional: {len(pending)} of {len(names)} reuse runs not finished** ({', '.join(pending)})."
        ),
        "",
        "| run | final success | AUC | first eval >= 0.5 | episodes per eval |",
        "|---|---|---|---|---|",
    ]
    for n in names:
        m = rows.get(n)
        out.append(
            f"| {n} | "
            + (
                " | ".join(
                    [f"{m['final']:.2f}", f"{m['auc']:.3f}", f"{m['first_past_half'] or 'never'}", str(m["episodes"])]
                )
                if m
                else "not finished | | |"
            )
            + " |"
        )
    out += ["", "| arm | runs | mean final | mean AUC |", "|---|---|---|---|"]
    for a in ["drs", *BASELINES]:
        if arms.get(a):
            out.append(f"| {a} | {len(arms[a])} of {expected[a]} | {means[a]['final']:.2f} | {means[a]['auc']:.3f} |")
    out += [
        "",
        "Decision rule (PREREGISTRATION.md): DrS beats X if mean final(DrS) - mean final(X) >= 0.2 and mean "
        "AUC(DrS) > mean AUC(X); X beats DrS the other way round; otherwise no difference.",
        "",
    ]
    for x, v in r["versus"].items():
        if v is None:
            out.append(f"- DrS vs {x}: not decidable yet (an arm is incomplete)")
        else:
            out.append(
                f"- DrS vs {x}: **{v['verdict']}** (final {v['d_final']:+.2f}, AUC {v['d_auc']:+.3f})"
                + (f"; {NO_SIGNAL}" if v["no_signal"] else "")
            )
    rec = r["recipe"]
    if rec:
        out.append(
            f"- The recipe on {folder.name}: **{rec['verdict']}** "
            f"({rec['hits']} of 6 DrS runs end at >= 0.5; per phase-1 reward {rec['per_reward'][0]} and "
            f"{rec['per_reward'][1]} of 3)"
            + (
                "; the rule names 4-6 of 6 with one phase-1 reward under 2 of 3 neither 'works' nor 'works partly': "
                "reported as 'works partly', the weaker"
                if rec["lopsided"]
                else ""
            )
        )
    else:
        out.append("- The recipe: not decidable yet (DrS arm incomplete)")
    return "\n".join(out) + "\n"


LABELS = {"sparse": "sparse", "semi_sparse": "semi-sparse", "dense": "dense"}
ROW_NOTES = {"dense": " (ManiSkill's dense reward, minus 1)"}


def claims_columns(folders: list[Path]) -> str:
    """The README claims table's pre-registered columns: one column per family, one row per claim of the rule."""

    def arm(r, a):
        n, of = len(r["arms"].get(a, [])), r["expected"][a]
        if not n:
            return f"no run finished (0 of {of})"
        m = r["means"][a]
        return f"{m['final']:.2f} [{m['auc']:.3f}]" + ("" if n == of else f" ({n} of {of} runs so far)")

    results = [decide(f) for f in folders]
    head = "| pre-registered claim (`results/recipe/`) | " + " | ".join(f"`{f.name}`" for f in folders) + " |"
    lines = [head, "|---|" + "---|" * len(folders)]
    lines.append("| DrS, 2 phase-1 rewards x 3 agent seeds | " + " | ".join(arm(r, "drs") for r in results) + " |")
    for x in BASELINES:
        cells = []
        for r in results:
            v = r["versus"][x]
            verdict = (
                (f"**{v['verdict']}**" + (f" (no signal: both below {MARGIN})" if v["no_signal"] else ""))
                if v
                else "not decidable yet"
            )
            cells.append(f"{verdict}; {LABELS[x]} {arm(r, x)}")
        lines.append(f"| DrS beats {LABELS[x]}{ROW_NOTES.get(x, '')} | " + " | ".join(cells) + " |")
    cells = []
    for r in results:
        rec = r["recipe"]
        cells.append(
            f"**{rec['verdict']}** ({rec['hits']} of 6 end at >= 0.5)"
            if rec
            else "not decidable yet ("
            + f"{sum(m['final'] >= WORKS_AT for m in r['arms'].get('drs', []))} of {len(r['arms'].get('drs', []))}"
            + " finished end at >= 0.5)"
        )
    lines.append(
        "| the recipe works (>= 4 of 6 DrS runs end at >= 0.5, >= 2 of 3 per phase-1 reward) | "
        + " | ".join(cells)
        + " |"
    )
    return "\n".join(lines) + "\n"


def main(argv: list[str]) -> int:
    if argv[:1] == ["--readme"]:  # the README claims table's pre-registered columns, from the committed records
        print(claims_columns([Path(f) for f in argv[1:]]), end="")
        return 0
    folder = Path(argv[0])
    text = decision_md(folder, decide(folder))
    (folder / "decision.md").write_text(text)
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
