#!/usr/bin/env bash
# The runs of results/ppo/PROTOCOL.md, from the repository root (a finished run is skipped), then the reports.
set -uo pipefail
R=runs/ppo
mkdir -p $R
for s in 0 1 2; do
  [ -f $R/maze/reuse-drs-s$s/summary.json ] || .venv/bin/drs-maze phase=reuse agent=ppo seed=$s reward.name=drs \
    reward.checkpoint=results/quickstart/seed$s/learn/reward.pt ppo.reward_scale=0.1 verbose=false overwrite=true \
    hydra.run.dir=$R/maze/reuse-drs-s$s
  [ -f $R/maze/reuse-sparse-s$s/summary.json ] || .venv/bin/drs-maze phase=reuse agent=ppo seed=$s reward.name=sparse \
    verbose=false overwrite=true hydra.run.dir=$R/maze/reuse-sparse-s$s
done
.venv/bin/drs-maze phase=report report.root=$R/maze report.out=results/ppo/maze
[ -f $R/turn_valve/learn-s0/summary.json ] || .venv/bin/drs-learn env=turn_valve algo=ppo seed=0 total_frames=100000 \
  stop_at_success=null eval.interval=20000 eval.episodes=10 checkpoint_interval=20000 torch_threads=1 \
  logger.progress_bar=false overwrite=true hydra.run.dir=$R/turn_valve/learn-s0
