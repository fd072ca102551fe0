"""The table of results/maze/controls/README.md from the runs' summary.json files.

.venv/bin/python results/maze/controls/summarize.py runs/maze/controls > results/maze/controls/controls.md
"""

import json
import sys
from pathlib import Path

from drs_torchrl.tools.maze_analysis import always_up_rate

root = Path(sys.argv[1] if len(sys.argv) > 1 else "runs/maze/controls")
print(
    "| run | phase, map | reward | greedy eval success at 200k (mean of the last 3 evals) | training success rows (of 21) "
    "| argmax_a R is a shortest-path move, this map (always-up reference) | greedy on R reaches the goal |"
)
print("|---|---|---|---|---|---|---|")
for s in sorted(root.glob("*/summary.json")):
    d = json.loads(s.read_text())
    rows = [line.split(",") for line in (s.parent / "train.csv").read_text().splitlines()]
    head, body = rows[0], rows[1:]
    ts = head.index("train_success")
    succ_rows = sum(1 for r in body if r[ts] not in ("", "nan") and float(r[ts]) > 0)
    diag = d.get("reward_diagnostics", {}).get(d["map"])
    opt = (
        f"{diag['optimal_action_rate']:.2f} ({diag.get('always_up_rate', always_up_rate(d['map'])):.2f})"
        if diag
        else "-"
    )
    greedy = f"{diag['greedy_success']:.2f}" if diag else "-"
    label = (
        d["reward"]
        + (f"[{d['reward_coords']}]" if d.get("reward_coords") else "")
        + ("[s']" if d.get("reward_input") == "next_state" else "")
        + (" alpha=0" if d.get("reward_alpha") == 0 else "")
        + f" x{d['reward_scale']:g}"
    )
    print(
        f"| `{s.parent.name}` | {d['phase']}, {d['map']} | {label} | {d['final_eval_success']:.2f} ({d['mean_eval_success_last3']:.2f}) "
        f"| {succ_rows} | {opt} | {greedy} |"
    )
