#!/usr/bin/env bash
# The selection study's record, from its worktree into this checkout, before a session ends: a report per round
# (finished, running or paused runs), then only the finished runs' files, with status.md. The decision is not made
# here: continue.sh makes it once every run of a round has finished. Commit afterwards.
#   results/selection/collect.sh [WORKTREE]        (default ../sel-wt)
set -euo pipefail
main=$(cd "$(dirname "$0")/../.." && pwd)
wt=$(cd "${1:-$main/../sel-wt}" && pwd)
finished() {
  "$main/.venv/bin/python" -c 'import sys, pathlib
from drs_torchrl.tools.study import run_state
sys.exit(run_state(pathlib.Path(sys.argv[1])) != "finished")' "$1"
}
for r in round1 round2; do
  rec=results/selection/$r
  [ -f "$wt/$rec/study.yaml" ] || continue
  (cd "$wt" && PYTHONPATH="$wt/src" .venv/bin/drs-study "$rec/study.yaml" --report "$rec" > /dev/null)
  for d in "$wt/$rec/run_files"/*/; do
    [ -d "$d" ] || continue
    n=$(basename "$d")
    if finished "$d"; then
      mkdir -p "$main/$rec/run_files/$n" && cp -r "$d". "$main/$rec/run_files/$n/"
    else
      rm -rf "$d"; echo "$r/$n: not finished, left out"
    fi
  done
  cp "$wt/$rec/status.md" "$main/$rec/"
  echo "$r: $(ls "$main/$rec/run_files" 2>/dev/null | wc -l) finished runs in the record"
done
