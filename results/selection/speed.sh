#!/usr/bin/env bash
# Step 0 of the agent selection (results/selection/PREREGISTRATION.md): each candidate's env steps/s as one drs-reuse
# run on 2 cores gets them, on an idle machine (nothing else may run: check with `uptime` first). The five candidates
# in turn, twice; then selection.py writes speed.json and, with `budgets`, round 1's study file.
#   bash results/selection/speed.sh            (from the pinned worktree; about 35 minutes)
set -euo pipefail
cd "$(dirname "$0")/../.."
candidates="sac_cpu sac_ln sac_ln_utd1_b128 crossq sac_ens10_ln"
dirs=()
for rep in 0 1; do
  for c in $candidates; do
    d=runs/selection_speed/$c-rep$rep
    dirs+=("$d")
    [ -f "$d/summary.json" ] && continue
    rm -rf "$d"
    .venv/bin/drs-reuse env=pick_cube env.split=test reward=dense algo="$c" algo.precision=fp32 total_frames=12000 \
      algo.learning_starts=4000 eval.episodes=0 logger.interval=1000 logger.progress_bar=false seed=0 "hydra.run.dir=$d" > /dev/null
    echo "$c rep $rep: done"
  done
done
.venv/bin/python results/selection/selection.py speed "${dirs[@]}"
