#!/usr/bin/env python
"""The descriptive facts that the recipe study's run tables quote, from a family's committed record.

    .venv/bin/python results/recipe/run_facts.py results/recipe/stack_cube

Per run (run_files/<run>/), three tables: the training windows (50 episodes; reach_stage_k and success_rate at each
log row): first logged step at 0.5 or more, the step from which it stays there, the best window and how many log
rows are above 0; the evaluations (20 fixed episodes): per stage, first step at 0.5 or more, final and best; the run:
env steps, the last resume (summary.json's resumed_from), env steps/s as the median of the log rows and since the last
start (summary.json; the whole run if never resumed). Not part of the decision rule (that is decide.py).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pandas as pd


def _k(step) -> str:
    return f"{round(int(step) / 1000)}k"


def _stages(frame: pd.DataFrame) -> list[str]:
    """The stage columns before success (reach_stage_1..N-1), then success_rate."""
    return sorted(c for c in frame.columns if c.startswith("reach_stage_"))[:-1] + ["success_rate"]


def training_facts(run: Path) -> dict:
    train = pd.read_csv(run / "train.csv")
    out = {"run": run.name}
    for c in _stages(train):
        rows = train[["step", c]].dropna()
        above = rows[rows[c] >= 0.5]
        below = rows.loc[rows[c] < 0.5, "step"]
        after = rows.loc[rows["step"] > (below.max() if len(below) else -1), "step"]  # the rows past the last dip
        stays = _k(after.iloc[0]) if len(after) else "never" if len(above) else "-"
        out[f"{c}: first >= 0.5"] = _k(above["step"].iloc[0]) if len(above) else "never"
        out[f"{c}: stays from"] = stays
        out[f"{c}: best"] = round(float(rows[c].max()), 2)
        out[f"{c}: rows > 0"] = f"{int((rows[c] > 0).sum())} of {len(rows)}"
    return out


def eval_facts(run: Path) -> dict:
    ev = pd.read_csv(run / "eval.csv").drop_duplicates("step", keep="last").sort_values("step")
    out = {"run": run.name}
    for c in _stages(ev):
        past = ev.loc[ev[c] >= 0.5, "step"]
        out[f"{c}: first >= 0.5"] = _k(past.iloc[0]) if len(past) else "never"
        out[f"{c}: final"] = round(float(ev[c].iloc[-1]), 2)
        out[f"{c}: best"] = round(float(ev[c].max()), 2)
    return out


def run_facts(run: Path) -> dict:
    train = pd.read_csv(run / "train.csv")
    summary = json.loads((run / "summary.json").read_text()) if (run / "summary.json").is_file() else {}
    resumed = summary.get("resumed_from")
    last = summary.get("env_steps_per_s")
    return {
        "run": run.name,
        "env steps": int(train["step"].max()),
        "last resume at": _k(resumed) if resumed else "not resumed",
        "env steps/s: median of log rows": round(float(train["env_steps_per_s"].median()), 1),
        "env steps/s: since the last start (summary.json)": round(float(last), 1) if last else "-",
    }


def main(family_dir: str) -> None:
    runs = sorted(p for p in (Path(family_dir) / "run_files").iterdir() if (p / "train.csv").is_file())
    for title, fn in (
        ("Training windows (50 episodes)", training_facts),
        ("Evaluations (20 fixed episodes)", eval_facts),
        ("Runs", run_facts),
    ):
        print(f"## {title}\n\n{pd.DataFrame([fn(r) for r in runs]).to_markdown(index=False)}\n")


if __name__ == "__main__":
    main(sys.argv[1])
