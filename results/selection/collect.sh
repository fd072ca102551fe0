#!/usr/bin/env bash
# The selection study's record, from its worktree into this checkout, before a session ends: a report per round
# (finished, running or paused runs), then only the finished runs' files, with status.md. The decision is not made
# here: continue.sh makes it once every run of a round has finished. Commit afterwards.
#   results/selection/collect.sh [WORKTREE]        (default ../sel-wt)
set -euo pipefail
main=$(cd "$(dirname "$0")/../.." && pwd)
wt=$(cd "${1:-$main/../sel-wt}" && pwd)
source "$main/results/keep_finished.sh"
for r in round1 round2; do
  rec=results/selection/$r
  [ -f "$wt/$rec/study.yaml" ] || continue
  (cd "$wt" && PYTHONPATH="$wt/src" .venv/bin/drs-study "$rec/study.yaml" --report "$rec" > /dev/null)
  keep_finished "$main" "$wt" "$rec" "$r"
  cp "$wt/$rec/status.md" "$main/$rec/"
  echo "$r: $(ls "$main/$rec/run_files" 2>/dev/null | wc -l) finished runs in the record"
done
