#!/usr/bin/env bash
# The maze study of results/maze/README.md: phase 1 (learn on the train map) and phase 2 (a fresh
# DQN on the test map, learned reward vs sparse), 3 seeds, one run at a time, then the report.
# Run from the repository root:  nohup results/maze/run_study.sh > runs/maze/study.log 2>&1 &
set -euo pipefail
cd "$(dirname "$0")/../.."
export RL_WARNINGS=0
ROOT=${ROOT:-runs/maze/study}
mkdir -p "$ROOT/logs"
for s in 0 1 2; do
  bin/drs-maze phase=learn seed=$s hydra.run.dir=$ROOT/learn-s$s > "$ROOT/logs/learn-s$s.log" 2>&1
done
for s in 0 1 2; do
  bin/drs-maze phase=reuse reward.name=drs reward.checkpoint=$ROOT/learn-s$s/reward.pt seed=$s \
    hydra.run.dir=$ROOT/reuse-drs-s$s > "$ROOT/logs/reuse-drs-s$s.log" 2>&1
  bin/drs-maze phase=reuse reward.name=sparse seed=$s hydra.run.dir=$ROOT/reuse-sparse-s$s > "$ROOT/logs/reuse-sparse-s$s.log" 2>&1
  # human-engineered dense baseline (added later, same budget): shows what DQN reaches here with a good reward
  bin/drs-maze phase=reuse reward.name=dense seed=$s hydra.run.dir=$ROOT/reuse-dense-s$s > "$ROOT/logs/reuse-dense-s$s.log" 2>&1
done
bin/drs-maze phase=report report.root=$ROOT report.out=results/maze
for s in 0 1 2; do cp "$ROOT/learn-s$s/reward_map.png" "results/maze/reward_map_s$s.png"; done
