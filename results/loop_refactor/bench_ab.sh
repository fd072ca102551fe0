#!/usr/bin/env bash
# Issue 46: drs-bench before (OLD, a commit) and after (this checkout) the one loop, interleaved A B A B in one session on
# one machine, so that drift and the other jobs on the machine hit both alike. Usage, from the repository root:
#   bash results/loop_refactor/bench_ab.sh 22d59b1 results/loop_refactor/bench
set -euo pipefail
OLD=${1:?usage: bench_ab.sh OLD_COMMIT OUT_DIR}; OUT=${2:?usage: bench_ab.sh OLD_COMMIT OUT_DIR}
ROOT=$(pwd); WT=$(mktemp -d)/old
git worktree add --detach "$WT" "$OLD" >/dev/null 2>&1; ln -s "$ROOT/.venv" "$WT/.venv"
trap 'git worktree remove --force "$WT"' EXIT
ARGS="--learn-frames 6000 --learning-starts 2000 --raw-steps 1000 --collect-steps 2000 --algos sac_cpu:bf16
      --collect-collectors inproc --collectors inproc:1 --no-plain --no-compile"
mkdir -p "$OUT"
for round in 1 2; do
  (cd "$WT" && PYTHONPATH="$WT/src" .venv/bin/drs-bench $ARGS --out "$ROOT/$OUT/old_$round" > "$ROOT/$OUT/old_$round.log" 2>&1)
  env -u PYTHONPATH .venv/bin/drs-bench $ARGS --out "$OUT/new_$round" > "$OUT/new_$round.log" 2>&1
done
echo "old: $(git rev-parse --short "$OLD"), new: $(git rev-parse --short HEAD);$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2)"
.venv/bin/python - "$OUT" <<'PY'
import json, sys
from pathlib import Path
out = Path(sys.argv[1])
rows = {}
for d in sorted(out.glob("*_[12]")):
    data = json.loads((d / "bench.json").read_text()) if (d / "bench.json").is_file() else json.loads(d.read_text())
    rows[d.name] = data
print(json.dumps({k: {kk: v for kk, v in r.items() if isinstance(v, (int, float))} for k, r in rows.items()}, indent=1))
PY
