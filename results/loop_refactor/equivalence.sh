#!/usr/bin/env bash
# Issue 46: the same runs with the code before the one loop (OLD, a commit) and with this checkout: the saved networks
# (policy.pt, reward.pt) tensor by tensor, and train.csv / eval.csv column by column (timing columns left out; the
# logged means of update statistics are averaged in another order, so they may differ in the 7th digit). Usage:
#   bash results/loop_refactor/equivalence.sh 22d59b1 > results/loop_refactor/equivalence.txt
set -euo pipefail
OLD=${1:?usage: equivalence.sh OLD_COMMIT}
ROOT=$(pwd); WT=$(mktemp -d)/old; OUT=$(mktemp -d)
git worktree add --detach "$WT" "$OLD" >/dev/null 2>&1
# the old code's own console scripts over this checkout's packages (the module layout changed since)
(cd "$WT" && bash "$ROOT/results/recipe/venv_view.sh" "$ROOT/.venv" "$WT/.venv" >/dev/null)
trap 'git worktree remove --force "$WT"' EXIT
COMMON="algo.hidden=[64,64] logger.interval=500 eval.interval=1500 eval.episodes=2 checkpoint_interval=1500"
COMMON+=" logger.progress_bar=false logger.tensorboard=false torch_threads=1 seed=5"
COMMON+=" algo.collector._target_=torchrl.collectors.Collector"
declare -A RUNS=(
  [sac_learn_turn_valve]="drs-learn env=turn_valve total_frames=3000 algo.learning_starts=500 stop_at_success=null $COMMON"
  [sac_learn_turn_valve_vice_raq]="drs-learn env=turn_valve reward=vice_raq total_frames=2000 algo.learning_starts=500 stop_at_success=null $COMMON"
  [sac_reuse_pick_cube_semi_sparse]="drs-reuse env=pick_cube reward=semi_sparse total_frames=2000 algo.learning_starts=500 $COMMON"
  [dqn_maze_learn]="drs-maze phase=learn num_envs=8 max_steps=40 total_frames=4096 dqn.frames_per_batch=128 dqn.learning_starts=256 dqn.batch_size=32 eval.interval=1024 eval.episodes=8 verbose=false tensorboard=false demos=10 seed=3"
)
echo "# old: $(git rev-parse --short "$OLD"), new: $(git rev-parse --short HEAD)$(git diff --quiet HEAD -- src conf || echo ' + uncommitted changes');$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2)$(grep -qw amx_bf16 /proc/cpuinfo && echo ' (AMX-BF16: Sapphire Rapids)')"
for name in "${!RUNS[@]}"; do
  read -r exe args <<<"${RUNS[$name]}"
  (cd "$WT" && PYTHONPATH="$WT/src" .venv/bin/$exe $args hydra.run.dir="$OUT/old_$name" >"$OUT/old_$name.log" 2>&1) \
    || { echo "$name: the old run failed, see $OUT/old_$name.log"; continue; }
  env -u PYTHONPATH .venv/bin/$exe $args hydra.run.dir="$OUT/new_$name" >"$OUT/new_$name.log" 2>&1 \
    || { echo "$name: the new run failed, see $OUT/new_$name.log"; continue; }
  .venv/bin/python - "$OUT/old_$name" "$OUT/new_$name" "$name" <<'PY'
import sys
from pathlib import Path
import pandas as pd
import torch

old, new, name = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]


def tensors(obj, prefix=""):
    """Every tensor of a checkpoint (nested dicts), by path."""
    if torch.is_tensor(obj):
        return {prefix: obj}
    if isinstance(obj, dict):
        return {k: v for key, val in obj.items() for k, v in tensors(val, f"{prefix}/{key}").items()}
    return {}


for f in ("policy.pt", "reward.pt"):
    found = [d / sub / f for d in (old, new) for sub in ("checkpoints", ".") if (d / sub / f).is_file()]
    if len(found) == 2:
        a, b = (tensors(torch.load(p, map_location="cpu", weights_only=False)) for p in found)
        same = a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
        print(f"{name} {f}: {len(a)} tensors, {'bitwise identical' if same else 'DIFFERENT'}")
for f in ("train.csv", "eval.csv"):
    if not (old / f).is_file():
        continue
    a, b = pd.read_csv(old / f), pd.read_csv(new / f)
    timing = ("_per_s", "frac_time", "wall_s", "rss_mib")  # machine measurements, not learning
    cols = [c for c in a.columns if c in b.columns and not any(t in c for t in timing)]
    diff = float((a[cols] - b[cols]).abs().max().max()) if len(a) == len(b) else float("nan")
    print(f"{name} {f}: rows {len(a)} / {len(b)}, columns only old {sorted(set(a.columns) - set(b.columns))}, "
          f"only new {sorted(set(b.columns) - set(a.columns))}, max |old - new| over {len(cols)} columns: {diff:g}")
PY
done
