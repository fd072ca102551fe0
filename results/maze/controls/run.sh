#!/usr/bin/env bash
# Issue 14's controlled maze experiments, one change at a time against the runs of results/maze/.
# Every run uses the agent reward scale at which phase 1 converges (dqn.reward_scale=0.1, see
# results/maze/README.md) unless its line says otherwise. Run from the repository root:
#   nohup results/maze/controls/run.sh > runs/maze/controls.log 2>&1 &
#   SEEDS="0 1 2" results/maze/controls/run.sh      # more seeds (default: seed 0)
# A run whose summary.json exists is skipped; the report is rebuilt at the end.
set -euo pipefail
cd "$(dirname "$0")/../../.."
export RL_WARNINGS=0
ROOT=${ROOT:-runs/maze/controls}
OUT=${OUT:-results/maze/controls}
SEEDS=${SEEDS:-0}
ONLY=${ONLY:-}          # a space-separated list of experiment names to run (default: all)
mkdir -p "$ROOT/logs"
X=dqn.reward_scale=0.1
PATCH=results/maze/patch_scaled/run_files   # the patch-only rewards learned at scale 0.1, seeds 0-2
run() {  # run NAME ARGS...
  local dir=$1; shift
  if [ -n "$ONLY" ] && [[ " $ONLY " != *" ${dir%-s*} "* ]]; then return; fi
  if [ -f "$ROOT/$dir/summary.json" ]; then echo "skip $dir (finished)"; return; fi
  echo "$(date -u +%H:%M:%S) $dir"
  bin/drs-maze "$@" overwrite=true hydra.run.dir="$ROOT/$dir" > "$ROOT/logs/$dir.log" 2>&1
}
for s in $SEEDS; do
  # 1. gates moved 3 columns towards the middle instead of swapped: the patch reward vs the baselines
  run shift3-drs_patch-s$s  phase=reuse map=test_shift3 reward.name=drs reward.checkpoint=$PATCH/learn-s$s/reward.pt $X seed=$s
  run shift3-semi_sparse-s$s phase=reuse map=test_shift3 reward.name=semi_sparse $X seed=$s
  run shift3-sparse-s$s     phase=reuse map=test_shift3 reward.name=sparse seed=$s
  # 2. the reward on s' (Sec. 4.3) instead of (s, a), learned on the train map, reused on three maps
  run learn-next_state-s$s  phase=learn reward.input=next_state $X seed=$s
  run test-drs_next_state-s$s   phase=reuse reward.name=drs reward.checkpoint=$ROOT/learn-next_state-s$s/reward.pt $X seed=$s
  run shift3-drs_next_state-s$s phase=reuse map=test_shift3 reward.name=drs reward.checkpoint=$ROOT/learn-next_state-s$s/reward.pt $X seed=$s
  run train-drs_next_state-s$s  phase=reuse map=train reward.name=drs reward.checkpoint=$ROOT/learn-next_state-s$s/reward.pt $X seed=$s
  # 3. DrS's constant part: the patch reward with its learned term switched off (alpha=0), test map
  run test-drs_patch_alpha0-s$s phase=reuse reward.name=drs reward.checkpoint=$PATCH/learn-s$s/reward.pt reward.reuse_alpha=0 $X seed=$s
  # 4. demonstrations as the only positives (the tabular argument's near-optimal success buffer)
  run learn-demos_only-s$s  phase=learn reward.positives=demos $X seed=$s
  run test-drs_demos_only-s$s phase=reuse reward.name=drs reward.checkpoint=$ROOT/learn-demos_only-s$s/reward.pt $X seed=$s
  #    ... and that reward on the map it was learned on, and on gates moved 3 columns
  run train-drs_demos_only-s$s phase=reuse map=train reward.name=drs reward.checkpoint=$ROOT/learn-demos_only-s$s/reward.pt $X seed=$s
  run shift3-drs_demos_only-s$s phase=reuse map=test_shift3 reward.name=drs reward.checkpoint=$ROOT/learn-demos_only-s$s/reward.pt $X seed=$s
  # 5. horizon and targets, the patch reward on the test map: the authors' gamma 0.8; one-step targets
  run test-drs_patch_gamma0.8-s$s phase=reuse reward.name=drs reward.checkpoint=$PATCH/learn-s$s/reward.pt dqn.gamma=0.8 $X seed=$s
  run test-drs_patch_1step-s$s  phase=reuse reward.name=drs reward.checkpoint=$PATCH/learn-s$s/reward.pt dqn.n_steps=1 $X seed=$s
  run test-drs_patch_mse-s$s    phase=reuse reward.name=drs reward.checkpoint=$PATCH/learn-s$s/reward.pt dqn.loss_function=l2 $X seed=$s
done
bin/drs-maze phase=report "report.root=[$ROOT]" report.out="$OUT"
