#!/usr/bin/env bash
# The reward probes of results/recipe/README.md ("Why the first DrS runs stall"), from the committed records:
# a family's learn_s<r> reward along 20 episodes (sampled actions) of its own phase-1 policy (train and test
# splits) and of the phase-2 agent that reused it (drs-learn<r>_s0, test split), with the input swap between the two.
# Not part of the pre-registration: a diagnosis written after those runs finished (stack_cube:0 and place_sphere:0
# first; the second phase-1 rewards, stack_cube:1 and place_sphere:1, added after their drs-learn1_s0 finished).
#   results/recipe/probe.sh                   # every probe
#   results/recipe/probe.sh stack_cube:1      # one family:reward pair
# Run from the repository root.
set -euo pipefail
export OMP_NUM_THREADS=1
for pair in "${@:-stack_cube:0 place_sphere:0 stack_cube:1 place_sphere:1}"; do
  for p in $pair; do
    f=${p%%:*} r=${p##*:}
    rec=results/recipe/$f/run_files
    .venv/bin/drs-probe --episodes 20 --seed 0 --reward $rec/learn_s$r/reward.pt --policy $rec/learn_s$r \
      --splits train test --out results/recipe/$f/probe/learn_s${r}_policy
    .venv/bin/drs-probe --episodes 20 --seed 0 --reward $rec/learn_s$r/reward.pt --policy $rec/drs-learn${r}_s0 \
      --swap-with $rec/learn_s$r --splits test --out results/recipe/$f/probe/drs-learn${r}_s0_policy
  done
done
