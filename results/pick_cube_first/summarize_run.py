#!/usr/bin/env python
"""Print a markdown table of a run's per-stage reach rates, discriminator accuracy and speed over time.

.venv/bin/python results/pick_cube_first/summarize_run.py results/pick_cube_first/phase1_pick_cube_demos_s0 [--every 20000]
"""

import argparse
import csv
import json
from pathlib import Path


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("run", type=Path)
    p.add_argument("--every", type=int, default=20000)
    a = p.parse_args()
    rows = list(csv.DictReader((a.run / "train.csv").open()))
    ev = (
        {int(float(r["step"])): r for r in csv.DictReader((a.run / "eval.csv").open())}
        if (a.run / "eval.csv").exists()
        else {}
    )
    stages = sorted(int(k.rsplit("_", 1)[1]) for k in rows[-1] if k.startswith("reach_stage_"))
    discs = sorted(int(k.rsplit("_", 1)[1]) for k in rows[-1] if k.startswith("disc_accuracy_"))
    head = (
        ["env steps"]
        + [f"train reach {k}" for k in stages]
        + [f"D_{k} acc" for k in discs]
        + ["reward mean", "env steps/s", "eval success", "eval reach 1"]
    )
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    picked, nxt = [], a.every
    for r in rows:
        step = int(float(r["step"]))
        if step >= nxt or r is rows[-1]:
            picked.append(r)
            nxt = (step // a.every + 1) * a.every
    f = lambda v, d=2: f"{float(v):.{d}f}" if v not in (None, "") else "-"
    for r in picked:
        step = int(float(r["step"]))
        e = ev.get(step) or next((ev[s] for s in sorted(ev) if abs(s - step) <= 64), None)
        cells = (
            [str(step)]
            + [f(r.get(f"reach_stage_{k}")) for k in stages]
            + [f(r.get(f"disc_accuracy_{k}")) for k in discs]
        )
        cells += [
            f(r.get("reward_mean"), 3),
            f(r.get("env_steps_per_s"), 0),
            f(e["success_rate"]) if e else "-",
            f(e["reach_stage_1"]) if e else "-",
        ]
        print("| " + " | ".join(cells) + " |")
    s = a.run / "summary.json"
    if s.exists():
        d = json.loads(s.read_text())
        print(
            f"\nWall time {d['wall_time_s'] / 60:.1f} min, {d['frames']} env steps, {d['updates']} SAC updates, "
            f"{d['disc_updates']} discriminator updates, {d['env_steps_per_s']:.1f} env steps/s overall; "
            f"stage buffers (episodes per stage): {d.get('stage_buffer_episodes')}"
        )


if __name__ == "__main__":
    main()
