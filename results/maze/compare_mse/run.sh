#!/usr/bin/env bash
# Issue 14: every reward of the paper's comparison on the maze, 3 seeds, in the configuration where DrS
# transferred best (../mse/): rewards learned in phase 1 with the Huber DQN (as ../patch_scaled/'s DrS
# rewards), and phase 2, a fresh DQN on the test map, with the MSE TD loss (dqn.loss_function=l2).
# The learned baselines (VICE-RAQ, ORIL, GAIL) are learned by ../baselines/run.sh's phase-1 command
# (same run folders, runs/maze/baselines/learn-*), then reused here with MSE; GAIL also as GAIL w/ stages.
# DrS, sparse, semi-sparse and dense with MSE are ../mse/'s runs (committed in ../mse/run_files/).
# Run from the repository root, one lane per core (a lane waits for the phase-1 runs of the other):
#   LANE=0 nohup results/maze/compare_mse/run.sh > runs/maze/compare_mse0.log 2>&1 &
#   LANE=1 nohup results/maze/compare_mse/run.sh > runs/maze/compare_mse1.log 2>&1 &
# A run whose summary.json exists is skipped; REPORT=1 results/maze/compare_mse/run.sh only writes the report.
set -euo pipefail
cd "$(dirname "$0")/../../.."
export RL_WARNINGS=0
LEARN=${LEARN:-runs/maze/baselines}
ROOT=${ROOT:-runs/maze/compare_mse}
OUT=${OUT:-results/maze/compare_mse}
LANE=${LANE:-all}
X=dqn.reward_scale=0.1
mkdir -p "$ROOT/logs" "$LEARN/logs"
i=0
run() {  # run ROOT NAME NEEDS ARGS...: in this lane only; waits for NEEDS (a summary.json, or -)
  local root=$1 dir=$2 needs=$3; shift 3
  i=$((i + 1))
  if [ "$LANE" != all ] && [ $((i % 2)) -ne "$LANE" ]; then return; fi
  if [ -f "$root/$dir/summary.json" ]; then echo "skip $dir (finished)"; return; fi
  while [ "$needs" != - ] && [ ! -f "$needs" ]; do sleep 20; done
  echo "$(date -u +%H:%M:%S) $dir"
  bin/drs-maze "$@" overwrite=true hydra.run.dir="$root/$dir" > "$root/logs/$dir.log" 2>&1
}
if [ -z "${REPORT:-}" ]; then
  for s in 0 1 2; do
    for m in vice_raq oril gail; do  # phase 1: ../baselines/run.sh's command (seed 0 ran there)
      run "$LEARN" learn-$m-s$s - phase=learn reward.name=$m $X seed=$s
    done
    for m in vice_raq oril gail; do
      run "$ROOT" reuse-$m-s$s "$LEARN/learn-$m-s$s/summary.json" phase=reuse reward.name=$m \
          reward.checkpoint=$LEARN/learn-$m-s$s/reward.pt $X dqn.loss_function=l2 seed=$s
    done
    run "$ROOT" reuse-gail_stages-s$s "$LEARN/learn-gail-s$s/summary.json" phase=reuse reward.name=gail_stages \
        reward.checkpoint=$LEARN/learn-gail-s$s/reward.pt $X dqn.loss_function=l2 seed=$s
  done
fi
if [ "$LANE" = all ] || [ "$LANE" = 0 ]; then
  bin/drs-maze phase=report "report.root=[$ROOT,results/maze/mse/run_files]" report.out="$OUT"
fi
