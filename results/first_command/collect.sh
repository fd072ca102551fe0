#!/usr/bin/env bash
# Copy the finished runs of a first-command folder into this record (no TensorBoard, no policies, no logs).
# usage: collect.sh RUNS_DIR RECORD_DIR     e.g. collect.sh ../fc-wt/runs/first_command results/first_command/selection
set -eu
rsync -a --prune-empty-dirs --exclude tb/ --exclude .hydra/ --exclude logs/ --exclude policy.pt --exclude '.drs-lock*' \
  --exclude quickstart.json "$1"/ "$2"/
# a run without summary.json did not finish: not part of the record
find "$2" -mindepth 1 -type d -name 'reuse-*' -o -mindepth 1 -type d -name 'learn' -o -mindepth 1 -type d -name 'train-s*' |
  while read -r d; do [ -f "$d/summary.json" ] || rm -rf "$d"; done
