"""Facts about a drs-learn / drs-reuse run read off its train.csv, as quoted in the READMEs here.

    .venv/bin/python results/families/run_facts.py RUN_DIR [RUN_DIR ...]

Per run: the first step at which the rolling training reach rate of stage 1 is >= 0.8, the first
step with a training success, how many rows had any stage-1 episode and the highest stage-1 rate,
and the reward on SAC batches (first and last row's mean, highest max).
"""

import csv
import sys

for run in sys.argv[1:]:
    rows = list(csv.DictReader(open(f"{run}/train.csv")))
    num = lambda r, k: float(r[k]) if r.get(k) not in (None, "", "nan") else None  # noqa: E731
    reach = [(int(float(r["step"])), num(r, "reach_stage_1")) for r in rows]
    succ = [(int(float(r["step"])), num(r, "success_rate")) for r in rows]
    first08 = next((s for s, v in reach if v is not None and v >= 0.8), None)
    first_succ = next((s for s, v in succ if v), None)
    any_reach = sum(1 for _, v in reach if v)
    means = [num(r, "reward_mean") for r in rows if num(r, "reward_mean") is not None]
    maxes = [num(r, "reward_max") for r in rows if num(r, "reward_max") is not None]
    print(f"{run}: {len(rows)} rows to step {reach[-1][0]}")
    print(f"  stage-1 reach >= 0.8 first at step {first08}; first training success at step {first_succ}")
    print(
        f"  rows with any stage-1 episode: {any_reach}; highest stage-1 rate {max(v for _, v in reach if v is not None):.2f}"
    )
    if means:
        print(
            f"  reward on SAC batches: mean {means[0]:.3f} (first row) -> {means[-1]:.3f} (last row), highest max {max(maxes):.3f}"
        )
