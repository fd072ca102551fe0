#!/usr/bin/env python
"""A/B timing of one SAC update (``Trainer._sac_step``) in one process, variants alternated in
40-update blocks so that load changes hit them alike. Produced the vmap / Adam / OMP figures in
``results/README.md`` ("Speed"):

    .venv/bin/python bin/ab_sac_update.py --threads 2 --compare vmap       # deactivate_vmap on/off
    .venv/bin/python bin/ab_sac_update.py --threads 1 --compare adam       # for-loop / foreach / fused Adam
    OMP_WAIT_POLICY=PASSIVE .venv/bin/python bin/ab_sac_update.py --threads 2 --compare vmap
"""
import argparse
import tempfile
import time

import torch
from hydra import compose, initialize_config_dir

from drs_torchrl.trainers.apps import conf_dir
from drs_torchrl.trainers.loop import Trainer


def trainer(extra):
    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        cfg = compose("learn", overrides=["algo=sac_cpu", "total_frames=1024", "algo.learning_starts=100000", "eval.episodes=0",
                                          "logger.progress_bar=false", "logger.tensorboard=false",
                                          "checkpoint_interval=1000000000", *extra])
    d = tempfile.mkdtemp()
    Trainer(cfg, "learn", d).run()  # 1024 real PickCube transitions
    return Trainer(cfg, "learn", d, resume=True)


def with_adam(tr, kind):
    kw = {"fused": {"fused": True}, "foreach": {"foreach": True}, "loop": {"foreach": False}}[kind]
    tr.optim_actor = torch.optim.Adam(list(tr.loss.actor_network_params.values(True, True)), lr=3e-4, **kw)
    tr.optim_critic = torch.optim.Adam(list(tr.loss.qvalue_network_params.values(True, True)), lr=3e-4, **kw)
    tr.optim_alpha = torch.optim.Adam([tr.loss.log_alpha], lr=3e-4, **kw)
    return tr


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--compare", choices=["vmap", "adam"], default="vmap")
    p.add_argument("--reps", type=int, default=4)
    a = p.parse_args()
    if a.compare == "vmap":
        variants = {"vmap": trainer([]), "novmap": trainer(["+algo.loss.deactivate_vmap=true"])}
    else:
        base = trainer([])
        variants = {k: (lambda k=k: with_adam(base, k)) for k in ("loop", "foreach", "fused")}
    torch.set_num_threads(a.threads)
    res = {k: [] for k in variants}
    for _ in range(a.reps):
        for k, v in variants.items():
            tr = v() if callable(v) else v
            for _ in range(3):
                tr._sac_step()
            t = time.perf_counter()
            for _ in range(40):
                tr._sac_step()
            res[k].append((time.perf_counter() - t) / 40 * 1e3)
    for k, v in res.items():
        print(f"{k}: ms per update {['%.1f' % x for x in v]}, min {min(v):.1f}")


if __name__ == "__main__":
    main()
