"""Mean / min / max of the training reach rate of stage 1 (or another column) (rolling over the last 50 episodes, one
row of train.csv every ~2k env steps) in env-step windows: the figures quoted for the long runs.

    .venv/bin/python results/families/reach_windows.py results/families/pick_and_place_long results/families/stack_cube_long
    .venv/bin/python results/families/reach_windows.py --step 50000 results/families/place_sphere_long   # uniform windows
    .venv/bin/python results/families/reach_windows.py --step 50000 --column success_rate RUN   # another column of train.csv
"""

import csv
import statistics
import sys

WINDOWS = [(0, 250_000), (250_000, 300_000), (300_000, 360_000), (360_000, 400_000), (400_000, 450_000)]

args = sys.argv[1:]
step = None
column = "reach_stage_1"
while args[:1] in (["--step"], ["--column"]):
    if args[0] == "--step":
        step = int(args[1])
    else:
        column = args[1]
    args = args[2:]

for run in args:
    rows = list(csv.DictReader(open(f"{run}/train.csv")))
    xs = [(float(r["frames"]), float(r[column])) for r in rows if r[column] not in ("", "nan")]
    windows = WINDOWS if step is None else [(lo, lo + step) for lo in range(0, int(max(f for f, _ in xs)) + 1, step)]
    print(run)
    for lo, hi in windows:
        v = [x for f, x in xs if lo < f <= hi]
        if v:
            print(
                f"  {lo // 1000:>3}-{hi // 1000}k: mean {statistics.mean(v):.2f}, min {min(v):.2f}, max {max(v):.2f} ({len(v)} rows)"
            )
