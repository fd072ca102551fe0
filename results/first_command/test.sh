#!/usr/bin/env bash
# The runs of PREREGISTRATION.md: seeds 5-9, each the README's first command with another seed, from a worktree
# pinned at the pre-registration commit (re-running continues: finished runs are kept):
#   git worktree add --detach ../fc-test-wt <commit> && cd ../fc-test-wt && ln -s ../main/.venv .venv
#   PYTHONPATH=$PWD/src nohup bash results/first_command/test.sh > runs/fc-test.log 2>&1 &
set -u
for s in 5 6 7 8 9; do
  .venv/bin/drs-quickstart seed=$s jobs=2 out=runs/first_command/test/seed$s || echo "seed $s: exit $?"
done
