#!/usr/bin/env bash
# Issue 14: every reward of the paper's comparison on the maze, same DQN, budget and demonstrations
# (100 shortest-path episodes of the train map), agent reward scale 0.1 for all. Phase 1 on the train map
# learns vice_raq / oril / gail; phase 2 (a fresh DQN on the test map) reuses them, and gail also as
# gail_stages. Run from the repository root:
#   nohup results/maze/baselines/run.sh > runs/maze/baselines.log 2>&1 &
#   SEEDS="0 1 2" results/maze/baselines/run.sh
# A run whose summary.json exists is skipped. The report also gathers the DrS and semi-sparse runs at
# scale 0.1 (patch_scaled/run_files) and the sparse and dense runs (run_files), committed earlier.
set -euo pipefail
cd "$(dirname "$0")/../../.."
export RL_WARNINGS=0
ROOT=${ROOT:-runs/maze/baselines}
OUT=${OUT:-results/maze/baselines}
SEEDS=${SEEDS:-0}
mkdir -p "$ROOT/logs"
X=dqn.reward_scale=0.1
run() {  # run NAME ARGS...
  local dir=$1; shift
  if [ -f "$ROOT/$dir/summary.json" ]; then echo "skip $dir (finished)"; return; fi
  echo "$(date -u +%H:%M:%S) $dir"
  bin/drs-maze "$@" overwrite=true hydra.run.dir="$ROOT/$dir" > "$ROOT/logs/$dir.log" 2>&1
}
for s in $SEEDS; do
  for m in vice_raq oril gail; do
    run learn-$m-s$s phase=learn reward.name=$m $X seed=$s
  done
  for m in vice_raq oril gail; do
    run reuse-$m-s$s phase=reuse reward.name=$m reward.checkpoint=$ROOT/learn-$m-s$s/reward.pt $X seed=$s
  done
  run reuse-gail_stages-s$s phase=reuse reward.name=gail_stages reward.checkpoint=$ROOT/learn-gail-s$s/reward.pt $X seed=$s
done
bin/drs-maze phase=report "report.root=[$ROOT,results/maze/patch_scaled/run_files,results/maze/run_files]" report.out="$OUT"
