#!/usr/bin/env bash
# results/maze_builders/compare.sh BEFORE AFTER: two captures side by side: train.csv without its wall-clock column,
# the saved policy.pt and reward.pt loaded and compared entry by entry (every tensor exactly), the composed configs
# key by key.
set -euo pipefail
py=${PY:-$(cd "$(dirname "$0")/../.." && pwd)/.venv/bin/python}
"$py" - "$1" "$2" <<'PY'
import csv
import json
import sys
from pathlib import Path

import torch

b, a = map(Path, sys.argv[1:])


def same(x, y) -> bool:
    if isinstance(x, dict) and isinstance(y, dict):
        return x.keys() == y.keys() and all(same(x[k], y[k]) for k in x)
    if isinstance(x, (list, tuple)) and isinstance(y, (list, tuple)):
        return len(x) == len(y) and all(map(same, x, y))
    if torch.is_tensor(x) and torch.is_tensor(y):
        return x.dtype == y.dtype and x.shape == y.shape and torch.equal(x, y)
    return x == y


def rows(path: Path):
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in csv.DictReader(path.open())]


print("| run | train.csv (wall_s left out) | policy.pt | reward.pt |\n|---|---|---|---|")
for run in ("learn", "reuse", "semi", "ppo", "gail"):
    cells = []
    for name in ("policy.pt", "reward.pt"):
        if not (b / run / name).is_file():
            cells.append("-")
            continue
        x, y = (torch.load(d / run / name, weights_only=False) for d in (b, a))
        cells.append("identical" if same(x, y) else "DIFFERENT")
    r0, r1 = rows(b / run / "train.csv"), rows(a / run / "train.csv")
    print(f"| {run} | {'identical' if r0 == r1 else 'DIFFERENT'} ({len(r1)} rows) | {cells[0]} | {cells[1]} |")


def diff(x, y, p=""):
    if isinstance(x, dict) and isinstance(y, dict):
        return [d for k in sorted(set(x) | set(y)) for d in diff(x.get(k), y.get(k), f"{p}.{k}" if p else k)]
    return [] if x == y else [f"{p}: {x!r} -> {y!r}"]


c0, c1 = (json.loads((d / "configs.json").read_text()) for d in (b, a))
print()
for k in c0:
    d = diff(c0[k], c1[k])
    print(f"- composed config `{k}`: " + ("identical" if not d else "; ".join(d)))
PY
