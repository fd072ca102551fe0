#!/usr/bin/env bash
# The fine-tuning study's record, from its worktree into this checkout: a report per study (finished, running or
# paused runs), then only the finished runs' files, with status.md (and, once stage B has runs, decision.md: the
# pre-registered rule on what finished, marked provisional until all have). Commit afterwards.
#   results/finetune/collect.sh [WORKTREE]        (default ../ft-wt)
set -euo pipefail
main=$(cd "$(dirname "$0")/../.." && pwd)
wt=$(cd "${1:-$main/../ft-wt}" && pwd)
source "$main/results/keep_finished.sh"
for s in calibration stack_cube place_sphere; do
  rec=results/finetune/$s
  [ -f "$wt/$rec/study.yaml" ] || continue
  (cd "$wt" && PYTHONPATH="$wt/src" .venv/bin/drs-study "$rec/study.yaml" --report "$rec" > /dev/null)
  keep_finished "$main" "$wt" "$rec" "$s"
  cp "$wt/$rec/status.md" "$main/$rec/"
  if [ "$s" != calibration ]; then (cd "$main" && .venv/bin/python results/finetune/decide.py "$rec" > /dev/null); fi
  echo "$s: $(ls "$main/$rec/run_files" 2>/dev/null | wc -l) finished runs in the record"
done
