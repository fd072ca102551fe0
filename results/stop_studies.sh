#!/usr/bin/env bash
# Before a session ends, after the studies' collect.sh: stop every running study (drs-study results/...) with SIGTERM.
# drs-study passes it to its runs, each saves its training state at its next batch boundary, and drs-study exits once
# they have; so the next session's continue.sh resumes every run, none starts again from 0 (a run killed before its
# first saved state would). Waits up to TIMEOUT_S seconds (default 600) and says what is still running after that.
#   results/stop_studies.sh [TIMEOUT_S]
set -uo pipefail
pids=$(pgrep -f "drs-study results/" | tr '\n' ' ')
[ -z "$pids" ] && { echo "no study running"; exit 0; }
echo "stopping studies (pids $pids) with SIGTERM"
kill -TERM $pids
deadline=$((SECONDS + ${1:-600})); left=$pids
while [ "$SECONDS" -lt "$deadline" ]; do
  left=$(for p in $pids; do kill -0 "$p" 2>/dev/null && echo "$p"; done)
  [ -z "$left" ] && { echo "every study stopped; its runs saved their states"; exit 0; }
  sleep 5
done
echo "still running after ${1:-600} s: $left"; exit 1
