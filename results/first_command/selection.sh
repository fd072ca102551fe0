#!/usr/bin/env bash
# The selection runs of SELECTION.md, one at a time (one torch thread), from a worktree pinned at the plan's commit:
#   git worktree add --detach ../fc-wt 44da1a5 && cd ../fc-wt && ln -s ../main/.venv .venv
#   PYTHONPATH=$PWD/src nohup bash ../main/results/first_command/selection.sh runs/first_command > runs/fc.log 2>&1 &
# Re-running skips what finished (drs-quickstart continues; a maze run with summary.json is done).
set -u
OUT=${1:-runs/first_command}
QS=results/quickstart   # seeds 0-2: the committed quickstart rewards
for s in 3 4; do
  .venv/bin/drs-quickstart seed=$s jobs=1 'baselines=[]' out=$OUT/seed$s
done
for s in 0 1 2 3 4; do
  if [ $s -le 2 ]; then ck=$QS/seed$s/learn/reward.pt; else ck=$OUT/seed$s/learn/reward.pt; fi
  d=$OUT/check/train-s$s
  [ -f $d/summary.json ] && continue
  .venv/bin/drs-maze phase=reuse map=train reward.name=drs reward.checkpoint=$ck dqn.reward_scale=0.1 \
    dqn.loss_function=l2 seed=$s overwrite=true hydra.run.dir=$d
done
