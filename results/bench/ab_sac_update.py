#!/usr/bin/env python
"""A/B timing of the learner's update (one discriminator step + one SAC step, as the loop does them)
in one process, variants alternated in blocks so that load changes hit them alike. Each variant is
a set of config overrides on a phase-1 PickCube trainer holding 1024 real transitions.

    .venv/bin/python results/bench/ab_sac_update.py --threads 2 --compare levers     # the issue-12 levers
    .venv/bin/python results/bench/ab_sac_update.py --threads 1 --compare vmap       # deactivate_vmap on/off
    .venv/bin/python results/bench/ab_sac_update.py --threads 1 --compare adam       # for-loop / foreach / fused Adam
    .venv/bin/python results/bench/ab_sac_update.py --algo sac_paper --compare precision
    .venv/bin/python results/bench/ab_sac_update.py --threads 1 --compare utd        # fewer, larger updates: learner ms per env step
    .venv/bin/python results/bench/ab_sac_update.py --threads 1 --compare schedules  # half the discriminator steps; batch 384 at UTD 1/3
"""

import argparse
import json
import tempfile
import time

import torch
from hydra import compose, initialize_config_dir

from drs_torchrl.precision import autocast
from drs_torchrl.apps.cli import conf_dir
from drs_torchrl.apps.build import Run

UNFUSED = ["algo.optim.fused=false", "reward.disc.fused=false"]
WHOLE = "<compile the whole update>"  # not a config option: loss, backward, Adam steps and target update in one torch.compile
COMPARISONS = {
    "levers": {
        "fp32, twin critics vmapped (before)": ["algo.precision=fp32", "algo.loss.deactivate_vmap=false"],
        "fp32, critics one after the other": ["algo.precision=fp32"],
        "bf16 autocast (auto where native)": ["algo.precision=bf16"],
        "bf16 autocast, compiled loss": ["algo.precision=bf16", "algo.compile=true"],
        "bf16 autocast, compiled whole update": ["algo.precision=bf16", WHOLE],
    },
    "precision": {"fp32": ["algo.precision=fp32"], "bf16": ["algo.precision=bf16"]},
    "vmap": {"vmap": ["algo.precision=fp32", "algo.loss.deactivate_vmap=false"], "novmap": ["algo.precision=fp32"]},
    # fewer, larger updates (issue 12): same gradient samples per env step (batch x UTD), the discriminators'
    # updates per env step kept by doubling their updates per SAC update; compare ms per env step
    "utd": {
        "fp32, batch 256, UTD 0.5": ["algo.precision=fp32", "algo.batch_size=256", "algo.utd=0.5"],
        "bf16, batch 256, UTD 0.5": ["algo.precision=bf16", "algo.batch_size=256", "algo.utd=0.5"],
        "bf16, batch 512, UTD 0.25": [
            "algo.precision=bf16",
            "algo.batch_size=512",
            "algo.utd=0.25",
            "algo.reward_updates_per_update=2",
        ],
        "fp32, batch 1024, UTD 0.5": ["algo.precision=fp32", "algo.batch_size=1024", "algo.utd=0.5"],
        "bf16, batch 1024, UTD 0.5": ["algo.precision=bf16", "algo.batch_size=1024", "algo.utd=0.5"],
        "bf16, batch 2048, UTD 0.25": [
            "algo.precision=bf16",
            "algo.batch_size=2048",
            "algo.utd=0.25",
            "algo.reward_updates_per_update=2",
        ],
        "bf16, batch 1024, UTD 0.25": [
            "algo.precision=bf16",
            "algo.batch_size=1024",
            "algo.utd=0.25",
            "algo.reward_updates_per_update=2",
        ],
    },
    # issue 12's cheaper schedules at batch 256's gradient samples per env step: half the discriminator steps,
    # or batch 384 at UTD 1/3 (the discriminators at 1.5 steps per SAC update); compare ms per env step
    "schedules": {
        "bf16, sac_cpu (batch 256, UTD 0.5, 1 discriminator step)": ["algo=sac_cpu", "algo.precision=bf16"],
        "bf16, sac_cpu_halfdisc (0.5 discriminator steps)": ["algo=sac_cpu_halfdisc", "algo.precision=bf16"],
        "bf16, sac_cpu_utd033 (batch 384, UTD 1/3, 1.5 discriminator steps)": [
            "algo=sac_cpu_utd033",
            "algo.precision=bf16",
        ],
        "bf16, sac_cpu_utd033_halfdisc (batch 384, UTD 1/3, 0.75 discriminator steps)": [
            "algo=sac_cpu_utd033_halfdisc",
            "algo.precision=bf16",
        ],
    },
    "adam": {
        "loop": [*UNFUSED, "+algo.optim.foreach=false"],
        "foreach": [*UNFUSED, "+algo.optim.foreach=true"],
        "fused": [],
    },
}


def trainer(algo, extra):
    whole = WHOLE in extra
    extra = [x for x in extra if x != WHOLE]
    algo = next((x.split("=", 1)[1] for x in extra if x.startswith("algo=")), algo)  # a variant's own algo config
    extra = [x for x in extra if not x.startswith("algo=")]
    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        cfg = compose(
            "learn",
            overrides=[
                f"algo={algo}",
                "total_frames=1024",
                "algo.learning_starts=100000",
                "eval.episodes=0",
                "logger.progress_bar=false",
                "logger.tensorboard=false",
                "+env.variant_overrides.goal_thresh=0.08",  # every discriminator has data
                "algo.collector._target_=torchrl.collectors.Collector",
                "checkpoint_interval=1000000000",
                *extra,
            ],
        )
    d = tempfile.mkdtemp()
    Run(cfg, "learn", d).run()  # 1024 real PickCube transitions
    tr = Run(cfg, "learn", d, resume=True)
    tr.sac_update = compiled_whole_update(tr) if whole else tr.updater.step
    return tr


def compiled_whole_update(tr):
    """The trainer's SAC step (same loss, optimisers and target updater) with everything after the
    sampling inside one ``torch.compile``: the route the issue suggests beyond compiling the loss."""
    opts = (tr.updater.optimizers["actor"], tr.updater.optimizers["critic"], tr.updater.optimizers["alpha"])

    def step(sample):
        with autocast(tr.precision, tr.device):
            out = tr.updater.loss(sample)
        (out["loss_actor"] + out["loss_qvalue"] + out["loss_alpha"]).backward()
        for opt in opts:
            opt.step()
            opt.zero_grad(set_to_none=True)
        tr.updater.target_updater.step()
        return out.detach()

    compiled = torch.compile(step)
    return lambda: compiled(tr.updater.sample())


def update(tr):
    tr.learner.update()
    tr.sac_update()


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--algo", default="sac_cpu")
    p.add_argument("--compare", choices=sorted(COMPARISONS), default="levers")
    p.add_argument("--reps", type=int, default=4)
    p.add_argument("--block", type=int, default=30)
    p.add_argument("--json", help="also write the results here")
    a = p.parse_args()
    variants = {k: trainer(a.algo, v) for k, v in COMPARISONS[a.compare].items()}
    torch.set_num_threads(a.threads)
    res = {k: [] for k in variants}
    for tr in variants.values():
        for _ in range(5):  # warm-up (and compilation)
            update(tr)
    for _ in range(a.reps):
        for k, tr in variants.items():
            t = time.perf_counter()
            for _ in range(a.block):
                update(tr)
            res[k].append((time.perf_counter() - t) / a.block * 1e3)
    out = []
    for k, v in res.items():
        utd = float(variants[k].cfg.algo.utd)
        out.append(
            {
                "variant": k,
                "overrides": COMPARISONS[a.compare][k],
                "ms_per_update_blocks": v,
                "ms_per_update_min": min(v),
                "utd": utd,
                "learner_ms_per_env_step": utd * min(v),
            }
        )
        print(
            f"{a.algo} threads={a.threads} {k}: ms per update (disc + SAC) {['%.1f' % x for x in v]}, min {min(v):.1f}; "
            f"learner ms per env step (x UTD {utd:g}) {utd * min(v):.1f}",
            flush=True,
        )
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"algo": a.algo, "threads": a.threads, "compare": a.compare, "results": out}, f, indent=2)


if __name__ == "__main__":
    main()
