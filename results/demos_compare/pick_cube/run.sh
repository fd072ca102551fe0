#!/usr/bin/env bash
# Issue 12, part 2 (see study.yaml): record the two demonstration files once (100 solver episodes on the
# training sizes, seed 0), then run the study, two runs side by side at one thread each. Re-run to continue.
#   nohup results/demos_compare/pick_cube/run.sh > runs/demos_compare_pick_cube.log 2>&1 &
set -euo pipefail
cd "$(dirname "$0")/../../.."
export RL_WARNINGS=0
D=results/demos_compare/pick_cube
mkdir -p runs
[ -f "$D/planner_joint.demos/meta.json" ] || .venv/bin/drs-demos --family pick_cube --variant train --num 100 --seed 0 \
    --control-mode pd_joint_pos --out "$D/planner_joint.demos"
[ -f "$D/planner_agent.demos/meta.json" ] || .venv/bin/drs-demos --family pick_cube --variant train --num 100 --seed 0 \
    --out "$D/planner_agent.demos"
exec .venv/bin/drs-study "$D/study.yaml" --jobs "${JOBS:-2}"
