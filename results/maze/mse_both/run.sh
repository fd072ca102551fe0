#!/usr/bin/env bash
# Issue 14: MSE in both phases. results/maze/mse/ reused patch rewards learned by the Huber DQN of
# phase 1 with an MSE phase-2 DQN (DrS 1.00 / 1.00 / 0.00). Here phase 1 also trains with MSE
# (dqn.loss_function=l2), so the reward is learned beside an agent that converges, and each seed's
# reward is reused by an MSE DQN on the test map. Sparse / semi-sparse with MSE are ../mse/'s runs.
# Run from the repository root (one lane per core; a run whose summary.json exists is skipped):
#   LANE=0 nohup results/maze/mse_both/run.sh > runs/maze/mse_both0.log 2>&1 &
# REPORT=1 results/maze/mse_both/run.sh only writes the report.
set -euo pipefail
cd "$(dirname "$0")/../../.."
export RL_WARNINGS=0
ROOT=${ROOT:-runs/maze/mse_both}
OUT=${OUT:-results/maze/mse_both}
SEEDS=${SEEDS:-0 1 2}
M="dqn.loss_function=l2 dqn.reward_scale=0.1 reward.coords=patch"
mkdir -p "$ROOT/logs"
run() {  # run NAME ARGS...
  local dir=$1; shift
  if [ -f "$ROOT/$dir/summary.json" ]; then echo "skip $dir (finished)"; return; fi
  echo "$(date -u +%H:%M:%S) $dir"
  bin/drs-maze "$@" hydra.run.dir="$ROOT/$dir" > "$ROOT/logs/$dir.log" 2>&1
}
if [ -z "${REPORT:-}" ]; then
  for s in $SEEDS; do
    run learn-s$s phase=learn $M seed=$s
    run reuse-drs-s$s phase=reuse reward.name=drs reward.checkpoint=$ROOT/learn-s$s/reward.pt $M seed=$s
  done
fi
bin/drs-maze phase=report "report.root=[$ROOT]" report.out="$OUT"
