# Sourced by a study's collect.sh: keep_finished MAIN WORKTREE RECORD LABEL copies the finished runs of the study whose
# record folder is RECORD (relative to both checkouts) from the worktree's report into MAIN's, and removes the partial
# copy of a run still going or paused from the worktree's record (so that its study never reads it as a record).
# "Finished" is the study's own rule (drs_torchrl.tools.study.run_state).
keep_finished() {
  local main=$1 wt=$2 rec=$3 label=$4 d n
  for d in "$wt/$rec/run_files"/*/; do
    [ -d "$d" ] || continue
    n=$(basename "$d")
    if "$main/.venv/bin/python" -c 'import sys, pathlib
from drs_torchrl.tools.study import run_state
sys.exit(run_state(pathlib.Path(sys.argv[1])) != "finished")' "$d"; then
      mkdir -p "$main/$rec/run_files/$n" && cp -r "$d". "$main/$rec/run_files/$n/"
    else
      rm -rf "$d"; echo "$label/$n: not finished, left out"
    fi
  done
}
