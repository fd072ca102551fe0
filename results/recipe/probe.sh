#!/usr/bin/env bash
# The reward probes of results/recipe/README.md ("Why the first DrS runs stall"), from the committed records:
# each family's learn_s0 reward along 20 episodes (sampled actions) of its own phase-1 policy (train and test
# splits) and of the phase-2 agent that reused it (drs-learn0_s0, test split), with the input swap between the two.
# Not part of the pre-registration: a diagnosis written after those runs finished. Run from the repository root.
set -euo pipefail
export OMP_NUM_THREADS=1
for f in stack_cube place_sphere; do
  rec=results/recipe/$f/run_files
  .venv/bin/drs-probe --episodes 20 --seed 0 --reward $rec/learn_s0/reward.pt --policy $rec/learn_s0 \
    --splits train test --out results/recipe/$f/probe/learn_s0_policy
  .venv/bin/drs-probe --episodes 20 --seed 0 --reward $rec/learn_s0/reward.pt --policy $rec/drs-learn0_s0 \
    --swap-with $rec/learn_s0 --splits test --out results/recipe/$f/probe/drs-learn0_s0_policy
done
