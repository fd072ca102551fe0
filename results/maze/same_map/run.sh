#!/usr/bin/env bash
# Issue 14, same-map control: the frozen phase-1 rewards reused by a fresh DQN on the *training* map
# (map=train), where the gates did not move. If DrS fails here too, what breaks is how the reward is
# used, not transfer. Both reward versions of results/maze/: the one-hot reward at agent scale 1 (the
# study, run_files/learn-s*) and the patch reward at scale 0.1 (patch_scaled/run_files/learn-s*).
set -euo pipefail
ROOT=${ROOT:-runs/maze/same_map}
export RL_WARNINGS=0
for s in 0 1 2; do
  d=$ROOT/onehot-x1-s$s
  [ -f $d/summary.json ] || bin/drs-maze overwrite=true phase=reuse map=train reward.name=drs \
      reward.checkpoint=results/maze/run_files/learn-s$s/reward.pt seed=$s hydra.run.dir=$d
  d=$ROOT/patch-x0.1-s$s
  [ -f $d/summary.json ] || bin/drs-maze overwrite=true phase=reuse map=train reward.name=drs reward.coords=patch dqn.reward_scale=0.1 \
      reward.checkpoint=results/maze/patch_scaled/run_files/learn-s$s/reward.pt seed=$s hydra.run.dir=$d
done
