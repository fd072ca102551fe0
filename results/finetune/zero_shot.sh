#!/usr/bin/env bash
# Stage 0 of results/finetune/PREREGISTRATION.md: each committed phase-1 policy, untouched, on the 20 fixed
# held-out episodes (deterministic actions), as the fine-tuning runs evaluate. From the pinned worktree:
#   bash results/finetune/zero_shot.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
mkdir -p results/finetune/zero_shot
for f in stack_cube place_sphere; do
  for k in 0 1; do
    out=results/finetune/zero_shot/$f-learn_s$k.json
    [ -f "$out" ] && { echo "$out: done"; continue; }
    .venv/bin/drs-eval "results/recipe/$f/run_files/learn_s$k" --split test --episodes 20 --episode-seed 1000 --out "$out"
  done
done
