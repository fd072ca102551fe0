"""Rows of a drs-maze run's train.csv with any training success, and the highest training success
rate: the "rows with a training success" columns of README.md.

    .venv/bin/python results/maze/success_rows.py results/maze/patch_scaled/run_files/{learn,reuse-drs,reuse-semi_sparse}-s{0,1,2}
"""

import csv
import sys

for run in sys.argv[1:]:
    rows = list(csv.DictReader(open(f"{run}/train.csv")))
    ts = [float(r["train_success"]) for r in rows if r["train_success"] not in ("", "nan")]
    print(
        f"{run}: {sum(1 for x in ts if x > 0)} of {len(rows)} rows with a training success, highest rate {max(ts, default=0.0):.2f}"
    )
