#!/usr/bin/env bash
# Issue 46: drs-bench before (OLD, a commit) and after (this checkout) the one loop, interleaved A B A B in one session on
# one machine, so that drift and the other jobs on the machine hit both alike. Usage, from the repository root:
#   bash results/loop_refactor/bench_ab.sh 22d59b1 results/loop_refactor/bench
set -euo pipefail
OLD=${1:?usage: bench_ab.sh OLD_COMMIT OUT_DIR}; OUT=${2:?usage: bench_ab.sh OLD_COMMIT OUT_DIR}
ROOT=$(pwd); WT=$(mktemp -d)/old
git worktree add --detach "$WT" "$OLD" >/dev/null 2>&1
# the old code's own console scripts over this checkout's packages (the module layout changed since)
(cd "$WT" && bash "$ROOT/results/recipe/venv_view.sh" "$ROOT/.venv" "$WT/.venv" >/dev/null)
trap 'git worktree remove --force "$WT"' EXIT
ARGS="--learn-frames 6000 --learning-starts 2000 --raw-steps 1000 --collect-steps 2000 --algos sac_cpu:bf16
      --collect-collectors inproc --collectors inproc:1 --no-plain --no-compile"
mkdir -p "$OUT"
for round in 1 2; do
  (cd "$WT" && PYTHONPATH="$WT/src" .venv/bin/drs-bench $ARGS --out "$ROOT/$OUT/old_$round" > "$ROOT/$OUT/old_$round.log" 2>&1)
  env -u PYTHONPATH .venv/bin/drs-bench $ARGS --out "$OUT/new_$round" > "$OUT/new_$round.log" 2>&1
done
echo "old: $(git rev-parse --short "$OLD"), new: $(git rev-parse --short HEAD);$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2)"
.venv/bin/python - "$OUT" <<'PY' | tee "$OUT/ab.md"
import json, sys
from pathlib import Path
out = Path(sys.argv[1])
runs = {d.name: json.loads((d / "bench.json").read_text()) for d in sorted(out.glob("*_[12]")) if (d / "bench.json").is_file()}
def rows(b):
    r = {"raw sim env steps/s": b["raw_sim_steps_per_s"]}
    r.update({f"collect ({k}) env steps/s": v for k, v in b["collect"].items()})
    for L in b["learn"]:
        r[f"phase 1 {L['algo']} {L['precision']} ({L['collector']}) env steps/s"] = L["env_steps_per_s"]
        r[f"phase 1 {L['algo']} {L['precision']} ({L['collector']}) updates/s"] = L["updates_per_s"]
    for c in b.get("components", []):
        for k in ("sac_update_ms", "disc_update_ms", "reward_recompute_ms"):
            if k in c:
                r[f"{c['algo']} {k}"] = c[k]
    return r
table = {name: rows(b) for name, b in runs.items()}
keys = list(next(iter(table.values())))
names = sorted(table, key=lambda n: (n.split("_")[1], n))
print("| measurement | " + " | ".join(names) + " | old mean | new mean | new / old |")
print("|---|" + "---|" * (len(names) + 3))
for k in keys:
    old = [table[n][k] for n in names if n.startswith("old") and k in table[n]]
    new = [table[n][k] for n in names if n.startswith("new") and k in table[n]]
    mo, mn = sum(old) / len(old), sum(new) / len(new)
    print(f"| {k} | " + " | ".join(f"{table[n].get(k, float('nan')):.1f}" for n in names) + f" | {mo:.1f} | {mn:.1f} | {mn / mo:.2f} |")
PY
