#!/usr/bin/env bash
# Issue 14: is a failing phase-2 run the reward's fault or the fresh agent's? In ../../quickstart/ (and
# ../mse/) DrS fails in seed 2 only. Swap: the seed-0 reward with the seed-2 agent, and the seed-2
# reward with the seed-0 agent; otherwise the quickstart's phase-2 DrS command (MSE DQN, test map).
# Run from the repository root (both at once, one per core):
#   nohup results/maze/seed_swap/run.sh > runs/maze/seed_swap.log 2>&1 &
set -euo pipefail
cd "$(dirname "$0")/../../.."
export RL_WARNINGS=0
ROOT=${ROOT:-runs/maze/seed_swap}
OUT=${OUT:-results/maze/seed_swap}
Q=${Q:-results/quickstart}
mkdir -p "$ROOT/logs"
run() {  # run NAME ARGS...
  local dir=$1; shift
  if [ -f "$ROOT/$dir/summary.json" ]; then echo "skip $dir (finished)"; return; fi
  echo "$(date -u +%H:%M:%S) $dir"
  bin/drs-maze "$@" overwrite=true hydra.run.dir="$ROOT/$dir" > "$ROOT/logs/$dir.log" 2>&1
}
M="phase=reuse reward.name=drs dqn.reward_scale=0.1 dqn.loss_function=l2 verbose=false"
run reward0-agent2 $M reward.checkpoint=$Q/seed0/learn/reward.pt seed=2 &
run reward2-agent0 $M reward.checkpoint=$Q/seed2/learn/reward.pt seed=0 &
wait
bin/drs-maze phase=report "report.root=[$ROOT]" report.out="$OUT"
