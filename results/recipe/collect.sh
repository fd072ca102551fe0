#!/usr/bin/env bash
# The study's record, from its worktree into this checkout: a report with this checkout's code (it pins each reuse
# run's reward by hash), then the finished runs' files, status.md, learn/, figures/ and decision.md (the
# pre-registered rule on the runs finished so far, marked provisional until all have). A run still going, or
# paused, stays out until it finishes (its partial copy is removed from the worktree's record too, so that the
# worktree's study never reads it as a record). Afterwards: update the tables of <family>/README.md, then
# tests/test_records.py and tests/test_paths.py, then commit.
#   results/recipe/collect.sh ../study-wt
set -euo pipefail
wt=$(cd "${1:?usage: results/recipe/collect.sh STUDY_WORKTREE}" && pwd)
main=$(cd "$(dirname "$0")/../.." && pwd)
finished() {  # the study's own rule: summary.json not interrupted, at its frames (or stopped at success)
  "$main/.venv/bin/python" -c 'import sys, pathlib
from drs_torchrl.tools.study import run_state
sys.exit(run_state(pathlib.Path(sys.argv[1])) != "finished")' "$1"
}
for f in stack_cube place_sphere; do
  rec=results/recipe/$f
  (cd "$wt" && env -u PYTHONPATH "$main/.venv/bin/drs-study" "$rec/study.yaml" --report "$rec" > /dev/null)
  for d in "$wt/$rec/run_files"/*/; do
    n=$(basename "$d")
    if finished "$d"; then
      mkdir -p "$main/$rec/run_files/$n" && cp -r "$d". "$main/$rec/run_files/$n/"
    else
      rm -rf "$d"; echo "$f/$n: not finished, left out"
    fi
  done
  cp "$wt/$rec/status.md" "$main/$rec/" && cp -r "$wt/$rec/learn" "$wt/$rec/figures" "$main/$rec/"
  (cd "$main" && .venv/bin/python results/recipe/decide.py "$rec" > /dev/null)   # decision.md, provisional until all finish
  echo "$f: $(ls "$main/$rec/run_files" | wc -l) runs in the record"
done
