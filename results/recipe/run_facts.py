#!/usr/bin/env python
"""The descriptive facts that results/recipe/README.md's run tables quote, from a family's committed record.

    .venv/bin/python results/recipe/run_facts.py results/recipe/stack_cube

Per finished run (run_files/<run>/): env steps, evaluation success (final, best), the first logged step at which
each stage's training-window rate (reach_stage_k, success_rate) reaches 0.5, the best window of each, and the
median env steps/s of the run's log rows. Not part of the decision rule (that is decide.py).
"""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd


def facts(run: Path) -> dict:
    train, ev = pd.read_csv(run / "train.csv"), pd.read_csv(run / "eval.csv")
    out = {
        "run": run.name,
        "env steps": int(train["step"].max()),
        "eval final": round(float(ev["success_rate"].iloc[-1]), 2),
        "eval best": round(float(ev["success_rate"].max()), 2),
    }
    cols = sorted(c for c in train.columns if c.startswith("reach_stage_"))[:-1] + ["success_rate"]
    for c in cols:
        rate = train[c].dropna()
        past = train.loc[rate.index[rate >= 0.5], "step"]
        out[f"{c} >= 0.5 at"] = f"{int(past.iloc[0]) // 1000}k" if len(past) else "never"
        out[f"{c} best"] = round(float(rate.max()), 2)
    out["env steps/s (median)"] = round(float(train["env_steps_per_s"].median()), 1)
    return out


def main(family_dir: str) -> None:
    runs = sorted(p for p in (Path(family_dir) / "run_files").iterdir() if (p / "train.csv").is_file())
    print(pd.DataFrame([facts(r) for r in runs]).to_markdown(index=False))


if __name__ == "__main__":
    main(sys.argv[1])
