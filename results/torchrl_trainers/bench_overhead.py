"""Per-update overhead of SACTrainer vs a plain loop over the same TorchRL pieces (CPU, 1 thread, tiny budget).

Same collector/env/nets/replay; both do 32 SAC updates per 64-frame batch (UTD 0.5), no logging.
Run from the repository root:  OMP_NUM_THREADS=1 .venv/bin/python results/torchrl_trainers/bench_overhead.py
"""

from __future__ import annotations

import json
import statistics
import time
import warnings

import torch

torch.set_num_threads(1)
warnings.filterwarnings("ignore")

from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.trainers.algorithms import SACTrainer

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from check_trainer import make_env, make_sac  # noqa: E402

FPB, TOTAL, STEPS, INIT = 64, 64 * 12, 32, 64


def pieces(seed):
    env = make_env(seed)
    actor, loss, target, optim = make_sac(env, seed)
    rb = ReplayBuffer(storage=LazyTensorStorage(10_000), batch_size=256)
    col = Collector(env, actor, frames_per_batch=FPB, total_frames=TOTAL, init_random_frames=INIT)
    return col, loss, target, optim, rb


def plain(seed=0):
    col, loss, target, optim, rb = pieces(seed)
    t_upd, n_upd, frames = 0.0, 0, 0
    t0 = time.perf_counter()
    for batch in col:
        frames += batch.numel()
        rb.extend(batch.reshape(-1))
        if frames < INIT:
            continue
        t = time.perf_counter()
        for _ in range(STEPS):
            out = loss(rb.sample())
            total = out["loss_actor"] + out["loss_qvalue"] + out["loss_alpha"]
            optim.zero_grad(set_to_none=True)
            total.backward()
            optim.step()
            target.step()
            n_upd += 1
        t_upd += time.perf_counter() - t
        col.update_policy_weights_()
    col.shutdown()
    return {"wall": time.perf_counter() - t0, "updates": n_upd}


def trainer(seed=0):
    col, loss, target, optim, rb = pieces(seed)
    tr = SACTrainer(
        collector=col,
        total_frames=TOTAL,
        frame_skip=1,
        optim_steps_per_batch=STEPS,
        loss_module=loss,
        optimizer=optim,
        replay_buffer=rb,
        target_net_updater=target,
        progress_bar=False,
        enable_logging=False,
        auto_log_optim_steps=False,
        save_trainer_interval=10**9,
        log_interval=10**9,
    )
    t0 = time.perf_counter()
    tr.train()
    return {"wall": time.perf_counter() - t0, "updates": tr._optim_count}


if __name__ == "__main__":
    res = {"plain": [], "sactrainer": []}
    for rep in range(3):
        for name, fn in (("plain", plain), ("sactrainer", trainer)):
            r = fn()
            res[name].append(round(r["wall"] / r["updates"] * 1e3, 3))
            res[name + "_updates"] = r["updates"]
    res["median_ms_per_update"] = {k: statistics.median(res[k]) for k in ("plain", "sactrainer")}
    res["ratio"] = round(res["median_ms_per_update"]["sactrainer"] / res["median_ms_per_update"]["plain"], 3)
    print(json.dumps(res, indent=1))
