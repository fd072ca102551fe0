#!/usr/bin/env bash
# The maze study of results/maze/README.md: phase 1 (learn on the train map) and phase 2 (a fresh
# DQN on the test map, learned reward vs baselines), 3 seeds, one run at a time, then the report.
# Run from the repository root:  nohup results/maze/run_study.sh > runs/maze/study.log 2>&1 &
#
#   ROOT       where the runs go (default runs/maze/study)
#   OUT        where the report goes (default results/maze)
#   DRS_ARGS   extra overrides for the DrS runs, phase 1 and 2 (e.g. "dqn.reward_scale=0.1")
#   BASELINES  baseline rewards of phase 2 (default "sparse dense")
#   BASE_ARGS  extra overrides for the baseline runs
#   EXTRA_ROOTS  more run folders the report gathers (e.g. another study's baselines)
#
# A run whose summary.json exists is skipped, so an interrupted study resumes where it stopped
# (a run cut in the middle starts again from scratch).
set -euo pipefail
cd "$(dirname "$0")/../.."
export RL_WARNINGS=0
ROOT=${ROOT:-runs/maze/study}
OUT=${OUT:-results/maze}
DRS_ARGS=${DRS_ARGS:-}
BASELINES=${BASELINES:-sparse dense}
BASE_ARGS=${BASE_ARGS:-}
EXTRA_ROOTS=${EXTRA_ROOTS:-}
mkdir -p "$ROOT/logs"
run() {  # run DIR ARGS...: one drs-maze run into $ROOT/DIR unless it has finished before
  local dir=$1; shift
  if [ -f "$ROOT/$dir/summary.json" ]; then echo "skip $dir (finished)"; return; fi
  echo "$(date -u +%H:%M:%S) $dir"
  # shellcheck disable=SC2068
  bin/drs-maze "$@" overwrite=true hydra.run.dir="$ROOT/$dir" > "$ROOT/logs/$dir.log" 2>&1
}
for s in 0 1 2; do
  # shellcheck disable=SC2086
  run learn-s$s phase=learn seed=$s $DRS_ARGS
done
for s in 0 1 2; do
  # shellcheck disable=SC2086
  run reuse-drs-s$s phase=reuse reward.name=drs reward.checkpoint="$ROOT/learn-s$s/reward.pt" seed=$s $DRS_ARGS
  for b in $BASELINES; do
    # shellcheck disable=SC2086
    run reuse-$b-s$s phase=reuse reward.name=$b seed=$s $BASE_ARGS
  done
done
roots="$ROOT"
for r in $EXTRA_ROOTS; do roots="$roots,$r"; done
bin/drs-maze phase=report "report.root=[$roots]" report.out="$OUT"
for s in 0 1 2; do cp "$ROOT/learn-s$s/reward_map.png" "$OUT/reward_map_s$s.png"; done
