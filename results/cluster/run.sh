#!/usr/bin/env bash
# The record of results/cluster/: drs-study --executor submitit-local with its driver stopped while the phase-1 job
# ran, that job then killed outright (SIGKILL to its controller, submitit's process and the run: a node lost), and
# the study started again. Run from the repository root: results/cluster/run.sh
set -euo pipefail
DRS=${DRS:-.venv/bin/drs-study}
S=results/cluster/study.yaml
OUT=results/cluster
ROOT=runs/cluster
job() { python3 -c "import json; print(json.load(open('$ROOT/logs/learn_s0.job.json'))['jobs'][-1]['job_id'])"; }
saved() { cat $ROOT/learn_s0/checkpoints/state/COMPLETE 2>/dev/null || echo 0; }
tree() { echo "$1"; for c in $(ps -o pid= --ppid "$1"); do tree "$c"; done; }

mkdir -p $ROOT
setsid $DRS $S --executor submitit-local > $OUT/driver1.txt 2>&1 &   # its own session, like nohup on a login node
driver=$!
until [ "$(saved)" -gt 0 ]; do sleep 0.2; done                      # the phase-1 run saved its first state
kill -TERM $driver; wait $driver || true                             # the driver stops; its job goes on
$DRS $S --status > $OUT/status_live_job.txt
j=$(job); kill -KILL $(tree "$j")                                    # the job dies outright
sleep 1
$DRS $S --status > $OUT/status_dead_job.txt
$DRS $S --executor submitit-local > $OUT/driver2.txt 2>&1            # started again: resubmits with resume=
$DRS $S --status > $OUT/status_final.txt
grep -h '^# 2' $ROOT/logs/*.log | sort | sed "s#$(cd "$(dirname "$DRS")" && pwd)/#.venv/bin/#" > $OUT/commands.txt                  # every command the jobs ran
cp $ROOT/logs/*.job.json $OUT/
$DRS $S --report $OUT
