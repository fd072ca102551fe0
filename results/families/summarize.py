"""Markdown tables for results/families/README.md from measure.json and the runs' train.csv / eval.csv / summary.json.

python3 results/families/summarize.py
"""

import csv
import json
from pathlib import Path

HERE = Path(__file__).parent
FAMILIES = ["pick_cube", "pick_and_place", "turn_valve", "stack_cube", "place_sphere", "cross_robot"]


def rows(path):
    return list(csv.DictReader(open(path))) if path.exists() else []


def f(x, nd=2):
    return "-" if x in (None, "") else f"{float(x):.{nd}f}"


m = json.loads((HERE / "measure.json").read_text())
print(
    "| family | obs / act (train) | obs / act (test) | env steps/s | reset ms: pool / one variant / reconfigure | random-policy reach |"
)
print("|---|---|---|---|---|---|")
for n in FAMILIES:
    r = m[n]
    extra = f" + task {r['train_task_obs']}" if "train_task_obs" in r else ""
    reach = ", ".join(f"{k} {v:.2f}" for k, v in r["random_reach"].items())
    print(
        f"| {n} | {r['train_obs']}{extra} / {r['train_act']} | {r['test_obs']} / {r['test_act']} | {r['steps_per_s']:.0f} | "
        f"{r['reset_ms_pool']:.1f} / {r['reset_ms_one_variant']:.1f} / {r['reset_ms_reconfigure']:.0f} | {reach} ({r['random_episodes']} episodes) |"
    )
print()
print(
    "| family | env steps done | wall s | env steps/s | SAC updates | train reach 1 / 2 / 3 (last 50 episodes) | best train reach 1 / 2 / 3 | eval (5 ep.) reach 1 / 2 / 3 | stage buffer episodes (0..N, demos in N) |"
)
print("|---|---|---|---|---|---|---|---|---|")
for n in FAMILIES:
    d = HERE / n
    tr, ev = rows(d / "train.csv"), rows(d / "eval.csv")
    if not tr:
        print(f"| {n} | (no run) |||||||")
        continue
    s = json.loads((d / "summary.json").read_text())
    k = len([c for c in tr[-1] if c.startswith("reach_stage_")])
    last = " / ".join(f(tr[-1][f"reach_stage_{i}"]) for i in range(1, k + 1))
    best = " / ".join(f(max(float(r[f"reach_stage_{i}"] or 0) for r in tr)) for i in range(1, k + 1))
    evs = " / ".join(f(ev[-1].get(f"reach_stage_{i}")) for i in range(1, k + 1)) if ev else "(no eval in budget)"
    print(
        f"| {n} | {s['frames']} | {s['wall_time_s']:.0f} | {s['env_steps_per_s']:.1f} | {s['updates']} | {last} | {best} | {evs} | "
        f"{s.get('stage_buffer_episodes')} |"
    )
