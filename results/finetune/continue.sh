#!/usr/bin/env bash
# The fine-tuning study (results/finetune/PREREGISTRATION.md), one command per session, run from the main checkout:
#   results/finetune/continue.sh [WORKTREE]        (default ../ft-wt)
# It makes the pinned worktree if missing (commit 5dfd1a3, its .venv a view of this checkout's), brings this
# checkout's record of finished runs into it (a fresh machine then skips them), and then, by where the study stands:
#   stage A (calibration) unfinished  -> (re)starts it in the background (--jobs 2), resuming what was interrupted;
#   stage A finished, no budgets yet  -> copies its record here, writes budget.md and the stage-B study files
#                                        (make_studies.py) and stops: commit them, then run this again;
#   budgets committed                 -> copies the stage-B study files into the worktree and starts stage B, one
#                                        job per family side by side.
# Before a session ends, to keep what finished: results/finetune/collect.sh [WORKTREE].
set -euo pipefail
main=$(cd "$(dirname "$0")/../.." && pwd)
wt=${1:-$main/../ft-wt}
pin=5dfd1a3
if [ ! -d "$wt" ]; then
  git -C "$main" worktree add --detach "$wt" "$pin"
  (cd "$wt" && bash "$main/results/recipe/venv_view.sh" "$main/.venv" "$wt/../ft-venv" > /dev/null && ln -sfn ../ft-venv .venv)
fi
[ "$(git -C "$wt" rev-parse --short=7 HEAD)" = "$pin" ] || { echo "$wt is not at $pin"; exit 2; }
export PYTHONPATH=$wt/src
running() { pgrep -f "drs-study results/finetune/$1/study.yaml" > /dev/null; }
for s in calibration stack_cube place_sphere; do  # the committed record: finished runs are skipped, not re-run
  [ -d "$main/results/finetune/$s/run_files" ] && mkdir -p "$wt/results/finetune/$s" && cp -rn "$main/results/finetune/$s/run_files" "$wt/results/finetune/$s/"
done
[ -d "$main/results/finetune/zero_shot" ] && cp -rn "$main/results/finetune/zero_shot" "$wt/results/finetune/"
cd "$wt"
left=$(.venv/bin/drs-study results/finetune/calibration/study.yaml --status | grep -E "^ *[a-z]+ +runs/" \
  | grep -cvE "^ *(finished|recorded) " || true)
if [ "$left" -gt 0 ]; then
  if running calibration; then echo "stage A is running ($left runs not finished)"; exit 0; fi
  mkdir -p runs/finetune_calibration
  nohup .venv/bin/drs-study results/finetune/calibration/study.yaml --jobs 2 >> runs/finetune_calibration/study.log 2>&1 &
  echo "stage A (re)started ($left runs not finished); log: $wt/runs/finetune_calibration/study.log"
  exit 0
fi
if ! git -C "$main" ls-files --error-unmatch results/finetune/budget.md > /dev/null 2>&1; then
  .venv/bin/drs-study results/finetune/calibration/study.yaml --report results/finetune/calibration > /dev/null
  cp -r results/finetune/calibration/run_files results/finetune/calibration/status.md "$main/results/finetune/calibration/"
  (cd "$main" && .venv/bin/python results/finetune/make_studies.py)
  echo "stage A finished: commit results/finetune/{budget.md,*/study.yaml,calibration/} in $main, then run this again"
  exit 0
fi
for f in stack_cube place_sphere; do
  mkdir -p "results/finetune/$f" && cp "$main/results/finetune/$f/study.yaml" "results/finetune/$f/study.yaml"
  cp -n "$main/results/finetune/budget.md" results/finetune/ 2>/dev/null || true
  if running "$f"; then echo "stage B on $f is running"; continue; fi
  mkdir -p "runs/finetune_$f"
  nohup .venv/bin/drs-study "results/finetune/$f/study.yaml" --jobs 1 >> "runs/finetune_$f/study.log" 2>&1 &
  echo "stage B on $f (re)started; log: $wt/runs/finetune_$f/study.log"
done
