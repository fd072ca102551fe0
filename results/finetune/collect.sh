#!/usr/bin/env bash
# The fine-tuning study's record, from its worktree into this checkout: a report per study (finished, running or
# paused runs), then only the finished runs' files, with status.md (and, once stage B has runs, decision.md: the
# pre-registered rule on what finished, marked provisional until all have). Commit afterwards.
#   results/finetune/collect.sh [WORKTREE]        (default ../ft-wt)
set -euo pipefail
main=$(cd "$(dirname "$0")/../.." && pwd)
wt=$(cd "${1:-$main/../ft-wt}" && pwd)
finished() {
  "$main/.venv/bin/python" -c 'import sys, pathlib
from drs_torchrl.tools.study import run_state
sys.exit(run_state(pathlib.Path(sys.argv[1])) != "finished")' "$1"
}
for s in calibration stack_cube place_sphere; do
  rec=results/finetune/$s
  [ -f "$wt/$rec/study.yaml" ] || continue
  (cd "$wt" && PYTHONPATH="$wt/src" .venv/bin/drs-study "$rec/study.yaml" --report "$rec" > /dev/null)
  for d in "$wt/$rec/run_files"/*/; do
    [ -d "$d" ] || continue
    n=$(basename "$d")
    if finished "$d"; then
      mkdir -p "$main/$rec/run_files/$n" && cp -r "$d". "$main/$rec/run_files/$n/"
    else
      rm -rf "$d"; echo "$s/$n: not finished, left out"
    fi
  done
  cp "$wt/$rec/status.md" "$main/$rec/"
  if [ "$s" != calibration ]; then (cd "$main" && .venv/bin/python results/finetune/decide.py "$rec" > /dev/null); fi
  echo "$s: $(ls "$main/$rec/run_files" 2>/dev/null | wc -l) finished runs in the record"
done
