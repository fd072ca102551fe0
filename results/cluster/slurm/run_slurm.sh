#!/usr/bin/env bash
# The record of results/cluster/slurm/: the same study through a one-node Slurm (bin/slurm-local.sh, as root), its
# phase-1 job cancelled while it ran. Run from the repository root: results/cluster/slurm/run_slurm.sh
set -euo pipefail
DRS=${DRS:-.venv/bin/drs-study}
S=results/cluster/slurm/study.yaml
OUT=results/cluster/slurm
ROOT=runs/cluster_slurm
job() { python3 -c "import json; print(json.load(open('$ROOT/logs/learn_s0.job.json'))['jobs'][-1]['job_id'])"; }
saved() { cat $ROOT/learn_s0/checkpoints/state/COMPLETE 2>/dev/null || echo 0; }

bin/slurm-local.sh > $OUT/slurm_local.txt
sinfo >> $OUT/slurm_local.txt
mkdir -p $ROOT
$DRS $S --executor slurm > $OUT/driver.txt 2>&1 &
driver=$!
until [ "$(saved)" -gt 0 ]; do sleep 0.2; done
$DRS $S --status > $OUT/status_running.txt
squeue >> $OUT/status_running.txt
scancel "$(job)"                                                      # the run saves on Slurm's SIGTERM
wait $driver
$DRS $S --status > $OUT/status_final.txt
ids=$(python3 -c "import glob, json; print(','.join(j['job_id'] for f in sorted(glob.glob('$ROOT/logs/*.job.json')) for j in json.load(open(f))['jobs']))")
squeue -t all -j "$ids" >> $OUT/status_final.txt                    # the study's jobs, as Slurm saw them end
grep -h '^# 2' $ROOT/logs/*.log | sort | sed "s#$(cd "$(dirname "$DRS")" && pwd)/#.venv/bin/#" > $OUT/commands.txt
cp $ROOT/logs/*.job.json $OUT/
$DRS $S --report $OUT
