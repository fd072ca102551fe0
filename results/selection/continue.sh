#!/usr/bin/env bash
# The agent selection (results/selection/PREREGISTRATION.md), one command per session, run from the main checkout:
#   results/selection/continue.sh [WORKTREE]        (default ../sel-wt)
# It makes the pinned worktree if missing (commit 6eeb605, its .venv a view of this checkout's), brings this
# checkout's committed files of the study into it, and then, by where the study stands:
#   no speed.json           -> step 0 (speed.sh) if the machine is idle (it stops otherwise), then the round-1 study
#                              file; both are copied here: commit them, then run this again;
#   round 1 unfinished      -> (re)starts it in the background (--jobs 2);
#   round 1 finished        -> its decision (and round 2's study file if there is a finalist): commit, run again;
#   round 2 unfinished      -> (re)starts it; finished -> its decision.
set -euo pipefail
main=$(cd "$(dirname "$0")/../.." && pwd)
wt=${1:-$main/../sel-wt}
pin=6eeb605
if [ ! -d "$wt" ]; then
  git -C "$main" worktree add --detach "$wt" "$pin"
  (cd "$wt" && bash "$main/results/recipe/venv_view.sh" "$main/.venv" "$wt/../sel-venv" > /dev/null && ln -sfn ../sel-venv .venv)
fi
[ "$(git -C "$wt" rev-parse --short=7 HEAD)" = "$pin" ] || { echo "$wt is not at $pin"; exit 2; }
export PYTHONPATH=$wt/src
sel=results/selection
for f in speed.json round1/study.yaml round2/study.yaml; do
  [ -f "$main/$sel/$f" ] && mkdir -p "$wt/$sel/$(dirname "$f")" && cp "$main/$sel/$f" "$wt/$sel/$f"
done
for r in round1 round2; do  # the committed record: finished runs are skipped, not re-run
  [ -d "$main/$sel/$r/run_files" ] && cp -rn "$main/$sel/$r/run_files" "$wt/$sel/$r/"
done
cd "$wt"
if [ ! -f "$sel/speed.json" ]; then
  load=$(cut -d' ' -f1 /proc/loadavg)
  if awk -v l="$load" 'BEGIN { exit !(l > 0.5) }'; then
    echo "step 0 needs an idle machine (load average $load): let the other jobs finish or pause them first"; exit 2
  fi
  bash "$sel/speed.sh"
  .venv/bin/python "$sel/selection.py" budgets
  mkdir -p "$main/$sel/round1" && cp "$sel/speed.json" "$main/$sel/" && cp "$sel/round1/study.yaml" "$main/$sel/round1/"
  echo "step 0 done: commit $sel/speed.json and $sel/round1/study.yaml in $main, then run this again"
  exit 0
fi
for r in round1 round2; do
  if [ ! -f "$sel/$r/study.yaml" ]; then  # round 2 exists only with a finalist
    echo "no $r study file: $( [ -f "$main/$sel/round1/decision.md" ] && echo "round 1 kept today's default, the study is done" || echo "not written yet")"
    exit 0
  fi
  left=$(.venv/bin/drs-study "$sel/$r/study.yaml" --status | grep -E "^ *[a-z]+ +runs/" | grep -cvE "^ *(finished|recorded) " || true)
  if [ "$left" -gt 0 ]; then
    if pgrep -f "drs-study $sel/$r/study.yaml" > /dev/null; then echo "$r is running ($left runs not finished)"; exit 0; fi
    mkdir -p "runs/selection_$r"
    nohup .venv/bin/drs-study "$sel/$r/study.yaml" --jobs 2 >> "runs/selection_$r/study.log" 2>&1 &
    echo "$r (re)started ($left runs not finished); log: $wt/runs/selection_$r/study.log"
    exit 0
  fi
  if [ ! -f "$main/$sel/$r/decision.md" ]; then
    .venv/bin/drs-study "$sel/$r/study.yaml" --report "$sel/$r" > /dev/null
    .venv/bin/python "$sel/selection.py" "$r"
    mkdir -p "$main/$sel/$r" && cp -r "$sel/$r/run_files" "$sel/$r/decision.md" "$sel/$r/status.md" "$main/$sel/$r/"
    [ -f "$sel/round2/study.yaml" ] && mkdir -p "$main/$sel/round2" && cp -n "$sel/round2/study.yaml" "$main/$sel/round2/"
    echo "$r decided: commit $sel/$r (and round2/study.yaml if written) in $main, then run this again"
    exit 0
  fi
done
echo "the selection study is done: results/selection/round*/decision.md"
