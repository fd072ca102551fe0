#!/usr/bin/env bash
# results/maze_builders/capture.sh SRC_ROOT OUT: short drs-maze runs (phase 1 DrS, phase 2 DrS, semi-sparse with
# one-step targets, PPO, GAIL) and the composed conf/maze.yaml under five override sets, with the code of checkout
# SRC_ROOT (run it with the code before and after a change, then compare.sh BEFORE AFTER).
set -euo pipefail
src=$1; out=$2; rm -rf "$out"; mkdir -p "$out"
export PYTHONPATH=$src/src DRS_NO_PROGRESS=1
py=${PY:-$(cd "$(dirname "$0")/../.." && pwd)/.venv/bin/python}
common="total_frames=12800 eval.interval=3200 dqn.learning_starts=1000 verbose=false tensorboard=false num_threads=1"
$py - "$out" <<'PY'
import json
import sys

from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf
from drs_torchrl.config_dir import conf_dir
import drs_torchrl.apps.hydra_record  # noqa: F401 (its resolvers)
sets = {
 "default": [],
 "qs_learn": ["reward.name=drs", "reward.coords=patch", "dqn.reward_scale=0.1", "dqn.loss_function=smooth_l1"],
 "qs_reuse": ["phase=reuse", "reward.name=drs", "reward.checkpoint=x.pt", "dqn.reward_scale=0.1", "dqn.loss_function=l2"],
 "ppo": ["agent=ppo", "ppo.lr=0.001"],
 "dqn_soft": ["dqn.target_update._target_=torchrl.objectives.SoftUpdate", "~dqn.target_update.value_network_update_interval", "+dqn.target_update.tau=0.01"],
}
res = {}
with initialize_config_dir(config_dir=conf_dir(), version_base=None):
    for k, ov in sets.items():
        try:
            c = compose("maze", overrides=ov)
            res[k] = OmegaConf.to_container(OmegaConf.masked_copy(c, [x for x in c if x != "hydra"]), resolve=True)
        except Exception as e:
            res[k] = f"ERROR {type(e).__name__}: {e}"
json.dump(res, open(sys.argv[1] + "/configs.json", "w"), indent=1, sort_keys=True)
PY
run() { name=$1; shift; $py -m drs_torchrl.apps.maze hydra.run.dir="$out/$name" $common "$@" > "$out/$name.log" 2>&1 || echo "$name failed"; }
run learn phase=learn seed=0 reward.name=drs reward.coords=patch dqn.reward_scale=0.1 dqn.loss_function=smooth_l1
run reuse phase=reuse seed=0 reward.name=drs reward.checkpoint="$out/learn/reward.pt" dqn.reward_scale=0.1 dqn.loss_function=l2
run semi phase=reuse seed=1 reward.name=semi_sparse dqn.reward_scale=0.1 dqn.loss_function=l2 dqn.n_steps=1
run ppo phase=learn seed=0 agent=ppo reward.name=drs
run gail phase=learn seed=0 reward.name=gail
echo done
