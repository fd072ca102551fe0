#!/usr/bin/env bash
# Issue 14, the lever left untried: more exploration in phase 2. The quickstart's phase-2 command (MSE DQN,
# test map, agent reward x0.1) with epsilon annealed over 80% of the run instead of 50% and to 0.1 instead
# of 0.05, on the quickstart's frozen rewards (../../quickstart/seed*/learn/reward.pt) and on sparse.
# Seed 2 first: its reward held every agent at 0.00 with the default schedule (../seed_swap/).
# Run from the repository root (one core):
#   nohup results/maze/explore/run.sh > runs/maze/explore.log 2>&1 &
# A run whose summary.json exists is skipped; REPORT=1 writes the report only.
set -euo pipefail
cd "$(dirname "$0")/../../.."
export RL_WARNINGS=0
ROOT=${ROOT:-runs/maze/explore}
OUT=${OUT:-results/maze/explore}
Q=results/quickstart
mkdir -p "$ROOT/logs"
run() {  # run NAME ARGS...
  local dir=$1; shift
  if [ -f "$ROOT/$dir/summary.json" ]; then echo "skip $dir (finished)"; return; fi
  echo "$(date -u +%H:%M:%S) $dir"
  bin/drs-maze "$@" overwrite=true hydra.run.dir="$ROOT/$dir" > "$ROOT/logs/$dir.log" 2>&1
}
E="phase=reuse dqn.loss_function=l2 dqn.eps_anneal_frac=0.8 dqn.eps_end=0.1 verbose=false"
if [ -z "${REPORT:-}" ]; then
  for s in ${SEEDS:-2 0 1}; do
    run reuse-drs-s$s $E reward.name=drs reward.checkpoint=$Q/seed$s/learn/reward.pt dqn.reward_scale=0.1 seed=$s
    run reuse-sparse-s$s $E reward.name=sparse seed=$s
  done
fi
bin/drs-maze phase=report "report.root=[$ROOT]" report.out="$OUT"
