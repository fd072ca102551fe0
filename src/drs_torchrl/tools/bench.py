"""``drs-bench``: measured speeds of the pipeline on this machine, in one run.

Measures, on the same task and machine:
  * ``raw_sim``: ManiSkill's gymnasium env stepped with random actions (with resets);
  * ``collect``: the TorchRL pipeline without learning: Collector + ManiSkillEnv + StageIndicator,
    random policy, transitions into the replay buffer, episodes assembled and filed into the stage
    buffers;
  * ``learn_<algo>``: phase 1 (SAC + discriminators, UTD of the config) after learning starts,
    env steps/s and gradient updates/s, for each algo config given;
  * ``plain``: the same algorithm as a plain single-file PyTorch loop (``drs_torchrl.tools.plain_loop``)
    at each config's batch size, measured right before and right after that config's pipeline rows
    (this machine's speed drifts within a run), and the pipeline's speed ratio over their mean;
  * ``--precisions fp32 bf16``: each pipeline row in each learner precision (``algo.precision``);
  * ``roofline``: the matrix-product FLOPs of one SAC update (counted by the profiler) against this
    machine's measured GEMM rate at the update's shapes, which bounds phase-1 env steps/s for *any*
    implementation of the algorithm on this machine (see :func:`roofline`).

Writes ``results/bench/bench.json`` and ``results/bench/bench.md``. Usage::

    drs-bench                       # PickCube, sac_cpu and sac_paper
    drs-bench --learn-frames 2048 --algos sac_cpu
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import torch

from drs_torchrl.runtime.console import at_least, console_script


def bench_raw_sim(env_id: str, steps: int, env_kwargs: dict, control_mode: str) -> float:
    import gymnasium as gym
    import mani_skill.envs  # noqa: F401

    import drs_torchrl.envs.variants  # noqa: F401

    env = gym.make(
        env_id,
        obs_mode="state",
        control_mode=control_mode,
        num_envs=1,
        sim_backend="physx_cpu",
        reward_mode="sparse",
        render_mode=None,
        **env_kwargs,
    )
    env.reset(seed=0)
    t = time.perf_counter()
    for _ in range(steps):
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        if bool((term | trunc).any()):
            env.reset()
    dt = time.perf_counter() - t
    env.close()
    return steps / dt


def bench_collect(family, steps: int, collector: str = "inproc") -> float:
    """Collection without learning: Collector + env + StageIndicator, random policy, transitions
    into the replay buffer, episodes assembled and filed into the stage buffers. ``background``:
    the env steps in a TorchRL ``AsyncCollector`` worker while this process files the data;
    ``background2``: two such workers (``MultiAsyncCollector``), each with its own simulator."""
    import functools

    from torchrl.collectors import AsyncCollector, Collector, MultiAsyncCollector
    from torchrl.data import LazyTensorStorage, ReplayBuffer

    from drs_torchrl.runtime.console import in_quiet_worker
    from drs_torchrl.data import StageBuffers, TrajectoryAssembler
    from drs_torchrl.envs.factory import make_family_env

    # a worker applies this process's console filter before it builds its simulator (ManiSkill's warnings)
    make = functools.partial(in_quiet_worker, make_family_env, family, "train", seed=0)
    rb = ReplayBuffer(storage=LazyTensorStorage(steps + 64))
    sb = StageBuffers(family.num_stages, list(family.reward_in_keys), capacity=steps + 64)
    asm = TrajectoryAssembler()
    warmup = 128  # the worker's start (imports, simulator build) is not part of the rate
    if collector == "background":
        collector = AsyncCollector(make, None, frames_per_batch=64, total_frames=steps + warmup)
    elif collector == "background2":
        makers = [functools.partial(in_quiet_worker, make_family_env, family, "train", seed=s) for s in (0, 1)]
        collector = MultiAsyncCollector(makers, None, frames_per_batch=64, total_frames=steps + warmup)
    else:
        collector = Collector(
            make(), None, frames_per_batch=64, total_frames=steps + warmup, auto_register_policy_transforms=False
        )
    n, t = 0, None
    for batch in collector:
        rb.extend(batch.reshape(-1))
        for ep in asm.add(batch):
            sb.add_trajectory(ep)
        n += batch.numel()
        if t is None and n >= warmup:
            t, n = time.perf_counter(), 0
    dt = time.perf_counter() - t
    collector.shutdown()
    return n / dt


def bench_components(
    algo: str, sizes: list[int], batch_reps: int = 50, precisions: tuple[str, ...] = ("fp32",), compile_too: bool = True
) -> dict:
    """Per-call times of the learner's parts on real PickCube data (phase 1, ``algo``):

    * ``sac_update_ms``: one SAC update (replay sample, reward recomputation, SACLoss, backward,
      three Adam steps, target update), eager and, if it compiles, with ``algo.compile=loss`` (``true``) and
      ``algo.compile=update`` (fp32);
    * ``reward_recompute_ms``: the learned reward (all discriminators, one pass) on a SAC batch;
    * ``disc_update_ms``: one discriminator update (a batch per discriminator from the stage buffers);
    * ``stage_sample_ms`` per stage-buffer size: drawing one discriminator batch, and filing one
      50-step episode, as the stage buffers grow from 1e3 to 1e6 transitions (must stay flat).
    """
    import tempfile

    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf
    from tensordict import TensorDict

    from drs_torchrl.apps.cli import conf_dir
    from drs_torchrl.apps.build import Run

    def per_call_ms(fn, n=batch_reps, warm=5):
        for _ in range(warm):
            fn()
        t = time.perf_counter()
        for _ in range(n):
            fn()
        return (time.perf_counter() - t) / n * 1e3

    top = max(sizes)
    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        cfg = compose(
            "learn",
            overrides=[
                f"algo={algo}",
                "total_frames=2048",
                "algo.learning_starts=100000",
                "eval.episodes=0",
                "logger.progress_bar=false",
                "logger.tensorboard=false",
                f"reward.stage_buffer_size={top}",
                "checkpoint_interval=1000000000",
            ],
        )
    out: dict = {"algo": algo, "batch_size": int(cfg.algo.batch_size), "width": int(max(cfg.algo.hidden))}
    with tempfile.TemporaryDirectory() as d:
        tr = Run(cfg, "learn", d)
        tr.run()  # 2048 real transitions in the replay and stage buffers
        tr = Run(cfg, "learn", d, resume=True)
        out["sac_update_ms"] = per_call_ms(tr.updater.step)
        out["sac_update_ms_by_precision"] = {"fp32": out["sac_update_ms"]}
        out["sac_update_gflop"] = sac_update_gflop(tr)
        out["threads"] = torch.get_num_threads()  # the update's ms above were measured at this many threads
        sample = tr.updater.replay.sample()
        nxt = sample.get("next")
        out["reward_recompute_ms"] = per_call_ms(lambda: tr.learned.reward(nxt), n=200)
        out["disc_update_ms"] = per_call_ms(tr.learner.update, n=200)
        states = torch.cat(tr.learner.stage_buffers.snapshot_parts())
        episode = tr.learner.stage_buffers.stage_data(0)[:50].clone()
        ep = TensorDict({"next": episode}, batch_size=episode.shape)
        sweep = []
        for size in sorted(sizes):
            while len(tr.learner.stage_buffers) < size:
                tr.learner.stage_buffers.extend(states[: size - len(tr.learner.stage_buffers)])
            tr.learner.stage_buffers.sample_discriminator_batch()  # sync the new slots' labels (once)
            n = len(tr.learner.stage_buffers)
            ms = per_call_ms(tr.learner.stage_buffers.sample_discriminator_batch, n=200)
            # filing adds 50 transitions per call (12 calls: at most 600, small beside the sizes swept)
            file_ms = per_call_ms(
                lambda: (
                    tr.learner.stage_buffers.add_trajectory(ep),
                    tr.learner.stage_buffers.sample_discriminator_batch(),
                ),
                n=10,
                warm=2,
            )
            sweep.append({"transitions": n, "sample_ms": ms, "file_episode_and_sample_ms": file_ms})
        out["stage_sample"] = sweep
        tr.close()
    for prec in precisions:  # a trainer of its own: the loss is built for its precision (no vmap under autocast)
        if prec == "fp32":
            continue
        pcfg = OmegaConf.merge(cfg, {"algo": {"precision": prec}})
        with tempfile.TemporaryDirectory() as d:
            Run(pcfg, "learn", d).run()
            tr = Run(pcfg, "learn", d, resume=True)
            out["sac_update_ms_by_precision"][prec] = per_call_ms(tr.updater.step)
            tr.close()
    if not compile_too:
        return out
    # algo.compile=loss (what true means; keys as before) and =update (the whole update compiled as one function)
    for scope, suffix in (("loss", ""), ("update", "_whole")):
        ccfg = OmegaConf.merge(cfg, {"algo": {"compile": scope, "precision": "fp32"}})
        with tempfile.TemporaryDirectory() as d:
            try:
                tr = Run(ccfg, "learn", d)
                tr.run()
                tr = Run(ccfg, "learn", d, resume=True)
                t = time.perf_counter()
                tr.updater.step()
                out[f"compile{suffix}_s"] = time.perf_counter() - t
                out[f"sac_update_compiled{suffix}_ms"] = per_call_ms(tr.updater.step)
                tr.close()
            except Exception as exc:  # reported, not hidden: the eager numbers stand
                out[f"compile{suffix}_error"] = f"{type(exc).__name__}: {exc}"[:500]
    return out


def sac_update_gflop(trainer) -> float:
    """Matrix-product GFLOPs of one SAC update (forward and backward of ``SACLoss`` on one replay
    batch), as counted by the PyTorch profiler (``mm``/``addmm``/``bmm`` in both passes)."""
    from torch.profiler import ProfilerActivity, profile

    sample = trainer.updater.replay.sample()
    with profile(activities=[ProfilerActivity.CPU], with_flops=True) as prof:
        out = trainer.updater.loss(sample)
        (out["loss_actor"] + out["loss_qvalue"] + out["loss_alpha"]).backward()
    for p in trainer.updater.loss.parameters():
        p.grad = None
    return sum(e.flops for e in prof.key_averages()) / 1e9


def gemm_gflops(batch: int, width: int, threads: int, reps: int = 400, dtype: torch.dtype = torch.float32) -> float:
    """Measured GEMM rate (GFLOP/s) of ``(batch, width) @ (width, width)`` in ``dtype``, the shape of
    the update's hidden layers, with ``threads`` torch threads: the best this machine does at that shape."""
    old = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        x, w = torch.randn(batch, width, dtype=dtype), torch.randn(width, width, dtype=dtype)
        out = torch.empty(batch, width, dtype=dtype)
        for _ in range(20):
            torch.mm(x, w, out=out)
        best = float("inf")
        for _ in range(3):
            t = time.perf_counter()
            for _ in range(reps):
                torch.mm(x, w, out=out)
            best = min(best, (time.perf_counter() - t) / reps)
    finally:
        torch.set_num_threads(old)
    return 2 * batch * width * width / best / 1e9


def roofline(res: dict) -> list[dict]:
    """Upper bound on phase-1 env steps/s on this machine, for any implementation, per algo config.

    Per env step the algorithm must do ``utd`` SAC updates (``gflop`` each, in matrix products
    alone) and one simulator step (``1 / raw`` s of one core). With ``C`` cores running GEMMs at the
    measured one-core rate ``g`` (perfect scaling, no other work, the simulator perfectly overlapped),
    env steps/s <= C / (utd * gflop / g + 1 / raw). The ratio of that bound to the plain loop's
    measured rate is the largest speed-up over it that this machine allows.
    """
    cores = os.cpu_count() or 1
    raw = res["raw_sim_steps_per_s"]
    plain = {(q["batch_size"], q.get("utd", 0.5)): q["env_steps_per_s"] for q in res.get("plain", [])}
    dtypes = {"fp32": torch.float32, "bf16": torch.bfloat16}
    out = []
    for c in res.get("components", []):
        bs, width = c["batch_size"], c.get("width", 256)
        learn = next((r for r in res["learn"] if r["algo"] == c["algo"]), {})
        utd = learn.get("utd", 0.5)
        ref = learn.get("plain_reference", {"batch_size": bs, "utd": 0.5})  # the plain loop its rows are compared with
        ref = (ref["batch_size"], ref["utd"])
        for prec, measured in (c.get("sac_update_ms_by_precision") or {"fp32": c["sac_update_ms"]}).items():
            g1 = gemm_gflops(bs, width, 1, dtype=dtypes[prec])
            gall = gemm_gflops(bs, width, cores, dtype=dtypes[prec])
            core_s = utd * c["sac_update_gflop"] / g1 + 1.0 / raw
            bound = cores / core_s
            row = {
                "algo": c["algo"],
                "precision": prec,
                "batch_size": bs,
                "utd": utd,
                "gflop_per_update": c["sac_update_gflop"],
                "gemm_gflops_1_thread": g1,
                f"gemm_gflops_{cores}_threads": gall,
                "cores": cores,
                "update_ms_lower_bound_all_cores": c["sac_update_gflop"] / gall * 1e3,
                "update_ms_measured": measured,
                "env_steps_per_s_bound": bound,
            }
            if ref in plain:
                row["plain_env_steps_per_s"] = plain[ref]
                row["bound_over_plain"] = bound / plain[ref]
            out.append(row)
    return out


def floor(res: dict) -> list[dict]:
    """How far each measured phase-1 row is from what this machine allows at its own settings (issue 64's goals).

    * the update: its measured ms (``components``, eager, at the threads it ran with) against its GEMM floor, the
      matrix-product GFLOPs of one update at the measured GEMM rate for that precision and thread count;
    * the loop: a ``learn`` row's env steps/s against its limit, ``min(raw simulator, compute bound)`` for a collector
      in the background (simulation beside the learner) and ``1 / (1/raw + 1/compute bound)`` in-process (the two
      take turns), where the compute bound is ``1 / (utd * floor)`` at the learner's threads and precision.
    Goals: the update at most 1.5x its floor; the loop at least 0.7 of its limit.
    """
    raw = res["raw_sim_steps_per_s"]
    dtypes = {"fp32": torch.float32, "bf16": torch.bfloat16}
    comps = {c["algo"]: c for c in res.get("components", [])}
    rate: dict[tuple, float] = {}

    def floor_ms(c: dict, prec: str, threads: int) -> float:
        key = (c["batch_size"], c.get("width", 256), threads, prec)
        if key not in rate:
            rate[key] = gemm_gflops(c["batch_size"], c.get("width", 256), threads, dtype=dtypes[prec])
        return c["sac_update_gflop"] / rate[key] * 1e3

    out = []
    for c in comps.values():
        threads = int(c.get("threads") or res.get("machine", {}).get("torch_threads") or 1)
        for prec, measured in (c.get("sac_update_ms_by_precision") or {"fp32": c["sac_update_ms"]}).items():
            f = floor_ms(c, prec, threads)
            out.append(
                {"what": "update", "algo": c["algo"], "precision": prec, "threads": threads, "measured_ms": measured,
                 "floor_ms": f, "over_floor": measured / f}
            )  # fmt: skip
    for r in res.get("learn", []):
        c = comps.get(r["algo"])
        if c is None or r.get("precision", "fp32") not in dtypes:
            continue
        threads = int(r.get("learner_threads") or res.get("machine", {}).get("torch_threads") or 1)
        compute = 1.0 / (r["utd"] * floor_ms(c, r.get("precision", "fp32"), threads) / 1e3)
        background = not str(r["collector"]).startswith("inproc")
        limit = min(raw, compute) if background else 1.0 / (1.0 / raw + 1.0 / compute)
        out.append(
            {"what": "loop", "algo": r["algo"], "precision": r.get("precision", "fp32"), "threads": threads,
             "collector": r["collector"], "env_steps_per_s": r["env_steps_per_s"], "raw_sim_steps_per_s": raw,
             "compute_bound_steps_per_s": compute, "limit_steps_per_s": limit,
             "of_limit": r["env_steps_per_s"] / limit}
        )  # fmt: skip
    return out


COLLECTORS = {
    "inproc": "torchrl.collectors.Collector",
    "background": "torchrl.collectors.AsyncCollector",
    "background2": "torchrl.collectors.MultiAsyncCollector",
}


def bench_learn(
    algo: str, frames: int, overrides: list[str], collector: str = "inproc", precision: str = "fp32"
) -> dict:
    """Phase-1 speed after learning starts: env steps/s and updates/s over ``frames`` steps, with the
    collector in this process (``inproc``) or in background processes (``background``, ``background2``);
    ``<collector>:T`` sets the learner's torch threads to ``T``."""
    import tempfile

    from hydra import compose, initialize_config_dir

    from drs_torchrl.apps.cli import conf_dir
    from drs_torchrl.apps.build import Run

    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        kind, _, threads = collector.partition(":")  # e.g. "background:2": the learner keeps 2 torch threads
        extra = ["+algo.collector.num_workers=2"] if kind == "background2" else []
        if threads:
            extra.append(
                f"+algo.collector.num_threads={int(threads)}" if kind != "inproc" else f"torch_threads={int(threads)}"
            )
        cfg = compose(
            "learn",
            overrides=[
                f"algo={algo}",
                f"algo.collector._target_={COLLECTORS[kind]}",
                f"algo.precision={precision}",
                *extra,
                *overrides,
            ],
        )
    start = int(cfg.algo.learning_starts)
    cfg.total_frames = start + frames
    cfg.eval.interval = 10**9
    cfg.eval.episodes = 0
    cfg.checkpoint_interval = 10**9
    cfg.logger.progress_bar = False
    cfg.logger.tensorboard = False
    cfg.logger.interval = frames  # one row for the warm-up, one for the timed part
    with tempfile.TemporaryDirectory() as d:
        tr = Run(cfg, "learn", d)
        # fill the warm-up without timing it
        tr.run()
        learner_threads = torch.get_num_threads()  # what the run set for its learner (a background collector: fewer)
        import csv

        rows = list(csv.DictReader(open(Path(d) / "train.csv")))
    timed = [r for r in rows if float(r["frames"]) > start]
    r = timed[-1]
    return {
        "algo": algo,
        "collector": collector,
        "precision": precision,
        "frac_time_updating": float(r["frac_time_updating"]),
        "batch_size": int(cfg.algo.batch_size),
        "utd": float(cfg.algo.utd),
        "frames_timed": frames,
        "env_steps_per_s": float(r["env_steps_per_s"]),
        "updates_per_s": float(r["updates_per_s"]),
        "collect_steps_per_s_within_learning": float(r["collect_steps_per_s"]),
        "learner_threads": learner_threads,
    }


def bench_checkpoint(transitions: int) -> dict:
    """Size and write/read time of the training state of a run holding ``transitions`` transitions.

    A real phase-1 Run (PickCube) collects 1024 real transitions; they are tiled until the
    replay buffer and the stage buffers each hold ``transitions``; then the state is saved (timed),
    and a second Run resumes from it (timed).
    """
    import shutil
    import tempfile

    from hydra import compose, initialize_config_dir

    from drs_torchrl.apps.cli import conf_dir
    from drs_torchrl.apps.build import Run

    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        cfg = compose(
            "learn",
            overrides=[
                "total_frames=1024",
                "algo.learning_starts=100000",
                "eval.episodes=0",
                "logger.progress_bar=false",
                "logger.tensorboard=false",
                f"algo.buffer_size={transitions}",
                f"reward.stage_buffer_size={transitions}",
                "checkpoint_interval=1000000000",
            ],
        )
    d = Path(tempfile.mkdtemp(prefix="drs-ckpt-"))
    try:
        tr = Run(cfg, "learn", d)
        tr.run()  # 1024 real transitions, saved state included
        tr = Run(cfg, "learn", d, resume=True)
        real = tr.updater.replay[: len(tr.updater.replay)].clone()
        states = torch.cat(tr.learner.stage_buffers.snapshot_parts())
        while len(tr.updater.replay) < transitions:
            tr.updater.replay.extend(real[: transitions - len(tr.updater.replay)])
        while len(tr.learner.stage_buffers) < transitions:
            tr.learner.stage_buffers.extend(states[: transitions - len(tr.learner.stage_buffers)])
        t = time.perf_counter()
        state = tr.save_training_state()
        write_s = time.perf_counter() - t
        size = sum(f.stat().st_size for f in state.rglob("*") if f.is_file())
        tr.close()
        t = time.perf_counter()
        tr2 = Run(cfg, "learn", d, resume=True)
        read_s = time.perf_counter() - t
        ok = len(tr2.updater.replay) == transitions and len(tr2.learner.stage_buffers) == transitions
        tr2.close()
    finally:
        shutil.rmtree(d, ignore_errors=True)
    return {
        "transitions": transitions,
        "bytes": size,
        "write_s": write_s,
        "resume_s": read_s,
        "restored": ok,
        "bytes_per_transition_replay_plus_stage": size / transitions,
    }


PAPER_UTD = 0.5  # the plain loop's reference UTD (the paper's)


def _paper_settings(q: dict) -> bool:
    """A plain-loop row at the paper's update schedule (UTD 0.5, one discriminator step per update): a reference row."""
    return q.get("utd", PAPER_UTD) == PAPER_UTD and q.get("disc_updates", 1) == 1


def algo_settings(algo: str) -> tuple[int, float, int, int]:
    """(SAC batch, UTD, discriminator steps per SAC update, discriminator batch per side) of ``drs-learn algo=ALGO``."""
    from hydra import compose, initialize_config_dir

    from drs_torchrl.apps.cli import conf_dir

    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        cfg = compose("learn", overrides=[f"algo={algo}"])
    return (
        int(cfg.algo.batch_size),
        float(cfg.algo.utd),
        float(cfg.algo.get("reward_updates_per_update") or 1),
        int(cfg.reward.disc.batch_size),
    )


def parse_algo(spec: str, default_precisions) -> tuple[str, list[str]]:
    """``sac_cpu:bf16`` -> ("sac_cpu", ["bf16"]); ``sac_paper`` -> ("sac_paper", the default precisions)."""
    algo, _, precs = spec.partition(":")
    chosen = [x for x in precs.split(",") if x] or list(default_precisions)
    bad = [x for x in chosen if x not in ("fp32", "bf16")]
    if bad:
        raise SystemExit(f"drs-bench: error: {spec!r}: precisions must be fp32 or bf16, got {bad}")
    return algo, chosen


@console_script("drs-bench")  # DRS_LIBRARY_MESSAGES=1 shows the libraries' notices again
def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="drs-bench", description=__doc__.split("\n")[0])
    p.add_argument("--family", default="pick_cube")
    p.add_argument("--raw-steps", type=at_least(1), default=3000)
    p.add_argument("--collect-steps", type=at_least(1), default=3008)
    p.add_argument("--learn-frames", type=at_least(1), default=2048)
    p.add_argument(
        "--algos",
        nargs="*",
        default=["sac_cpu", "sac_cpu_utd025:bf16", "sac_paper", "sac_paper_utd025:bf16"],
        help="algo configs (conf/algo/), each optionally with ':PREC[,PREC]', its own learner precisions "
        "(default: --precisions)",
    )
    p.add_argument(
        "--collect-collectors",
        nargs="*",
        default=["inproc", "background", "background2"],
        choices=sorted(COLLECTORS),
        help="collectors for the collection-only measurement",
    )
    p.add_argument(
        "--collectors",
        nargs="*",
        default=["inproc", "background", "background:2"],
        help="collectors for the phase-1 measurements: inproc, background, background2 (two workers), "
        "optionally with ':T' for T learner torch threads (default: a background collector leaves "
        "the learner cpu_count - workers threads)",
    )
    p.add_argument(
        "--precisions",
        nargs="*",
        default=["fp32", "bf16"],
        choices=["fp32", "bf16"],
        help="learner precisions of the phase-1 measurements (algo.precision); the plain loop is fp32",
    )
    p.add_argument(
        "--stage-sizes",
        nargs="*",
        type=at_least(1),
        default=[1_000, 10_000, 100_000, 1_000_000],
        help="stage-buffer sizes for the sampling-time sweep (empty: skip the component timings)",
    )
    p.add_argument(
        "--learning-starts",
        type=at_least(0),
        default=None,
        metavar="N",
        help="override algo.learning_starts, the untimed warm-up of the phase-1 rows (smoke runs only)",
    )
    p.add_argument("--out", default="results/bench")
    p.add_argument("--no-plain", action="store_true", help="skip the plain single-file loop baseline")
    p.add_argument("--no-compile", action="store_true", help="skip the algo.compile=true timing of the components")
    p.add_argument(
        "--checkpoint",
        type=at_least(0),
        default=0,
        metavar="N",
        help="also measure the training-state checkpoint of a run holding N transitions (e.g. 1000000)",
    )
    a = p.parse_args(argv)
    from drs_torchrl.runtime.rundir import check_writable
    from drs_torchrl.tasks import get_family

    fam = get_family(a.family)  # both checked before the benchmark starts
    check_writable(a.out, "--out", folder=True)
    learn_overrides = [f"env={a.family}"] + (
        [] if a.learning_starts is None else [f"algo.learning_starts={a.learning_starts}"]
    )
    kw = fam.variant_kwargs("train")
    threads = torch.get_num_threads()
    res: dict = {
        "command": "drs-bench " + " ".join(sys.argv[1:] if argv is None else argv),
        "machine": {
            "cpus": os.cpu_count(),
            "torch_threads": threads,
            "platform": platform.platform(),
            "torch": torch.__version__,
            "cuda": torch.cuda.is_available(),
        },
        "family": a.family,
    }
    print("raw simulator ...", flush=True)
    res["raw_sim_steps_per_s"] = bench_raw_sim(fam.env_id, a.raw_steps, kw, fam.control_mode)
    print(f"  {res['raw_sim_steps_per_s']:.0f} steps/s", flush=True)
    res["collect"] = {}
    for c in a.collect_collectors:
        print(f"collection only, {c} collector ...", flush=True)
        res["collect"][c] = bench_collect(fam, a.collect_steps, collector=c)
        torch.set_num_threads(threads)  # a background collector lowers this process's threads while it runs
        print(
            f"  {res['collect'][c]:.0f} steps/s ({res['collect'][c] / res['raw_sim_steps_per_s']:.2f}x raw)", flush=True
        )
    res["learn"] = []
    res["plain"] = []
    from drs_torchrl.tools.plain_loop import run_plain_drs
    from drs_torchrl.precision import native_bf16

    res["machine"]["native_bf16"] = native_bf16("cpu")

    def plain(bs: int, disc_batch: int, utd: float = 0.5, disc_updates: float = 1) -> dict:
        print(
            f"plain single-file loop, batch {bs}, UTD {utd:g}, {disc_updates:g} discriminator step(s) per update ...",
            flush=True,
        )
        q = run_plain_drs(
            fam.env_id,
            kw,
            fam.stage_keys,
            bs,
            a.learn_frames,
            utd=utd,
            disc_updates=disc_updates,
            disc_batch_size=disc_batch,
        )
        torch.set_num_threads(threads)
        print(f"  {q['env_steps_per_s']:.1f} env steps/s", flush=True)
        return q

    def mean_of(before: dict, after: dict) -> dict:
        return {
            **before,
            "env_steps_per_s": (before["env_steps_per_s"] + after["env_steps_per_s"]) / 2,
            "updates_per_s_overall": (before["updates_per_s_overall"] + after["updates_per_s_overall"]) / 2,
            "before": before["env_steps_per_s"],
            "after": after["env_steps_per_s"],
        }

    for spec in a.algos:
        algo, precisions = parse_algo(spec, a.precisions)
        bs, utd, rupd, dbs = algo_settings(algo)
        # the reference: the plain loop at the paper's UTD (0.5) with the same gradient samples per env step
        # (batch x UTD), measured right before and right after this config's pipeline rows (this machine's
        # speed drifts within a run); the ratio is taken over the mean of the two
        ref_bs = round(bs * utd / PAPER_UTD)
        before = None if a.no_plain else plain(ref_bs, dbs)
        rows = []
        for c in a.collectors:
            for prec in precisions:
                print(f"phase 1, {algo}, {c} collector, {prec} ...", flush=True)
                r = bench_learn(algo, a.learn_frames, learn_overrides, collector=c, precision=prec)
                torch.set_num_threads(threads)
                rows.append(r)
                print(f"  {r['env_steps_per_s']:.1f} env steps/s, {r['updates_per_s']:.1f} updates/s", flush=True)
        res["learn"] += rows
        if before is not None:
            q = mean_of(before, plain(ref_bs, dbs))
            q["reference_for"] = [algo]
            for r in rows:
                r["over_plain"] = r["env_steps_per_s"] / q["env_steps_per_s"]
                r["plain_reference"] = {"batch_size": ref_bs, "utd": PAPER_UTD}
            res["plain"].append(q)
            if utd != PAPER_UTD or rupd != 1:  # the same lever in the plain loop: what it would gain from fewer updates
                same = plain(bs, dbs, utd, rupd)
                same["reference_for"] = [f"{algo} (same batch and UTD)"]
                for r in rows:
                    r["over_plain_same_updates"] = r["env_steps_per_s"] / same["env_steps_per_s"]
                res["plain"].append(same)
    res["components"] = []
    if a.stage_sizes:
        for spec in a.algos:
            algo, precisions = parse_algo(spec, a.precisions)
            print(f"component timings, {algo} ...", flush=True)
            res["components"].append(
                bench_components(algo, a.stage_sizes, precisions=tuple(precisions), compile_too=not a.no_compile)
            )
        print("roofline (GEMM rate at the update's shapes) ...", flush=True)
        res["roofline"] = roofline(res)
        res["floor"] = floor(res)
    if a.checkpoint:
        print(f"checkpoint of a {a.checkpoint}-transition run ...", flush=True)
        res["checkpoint"] = c = bench_checkpoint(a.checkpoint)
        print(
            f"  {c['bytes'] / 1e6:.0f} MB, written in {c['write_s']:.1f}s, resumed in {c['resume_s']:.1f}s", flush=True
        )
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench.json").write_text(json.dumps(res, indent=2))
    md = render_markdown(res)
    (out / "bench.md").write_text(md)
    print(md)
    return 0


def render_markdown(res: dict) -> str:
    m = res["machine"]
    raw = res["raw_sim_steps_per_s"]
    lines = [
        f"# drs-bench on {res['family']}",
        "",
        f"Command: `{res['command']}`",
        "",
        f"Machine: {m['cpus']} CPUs, {m['torch_threads']} torch threads, {m['platform']}, torch {m['torch']}, CUDA {m['cuda']}"
        + (f", native bf16: {'yes' if m['native_bf16'] else 'no (bf16 is emulated)'}" if "native_bf16" in m else ""),
        "",
        "`vs plain loop`: against the plain fp32 loop at the paper's UTD 0.5 with the same gradient samples per env step "
        "(batch x UTD); `vs plain loop, same lever`: against the plain loop at the row's own batch and UTD.",
        "",
        "| measurement | env steps/s | updates/s | vs plain loop | vs plain loop, same lever |",
        "|---|---|---|---|---|",
        f"| raw simulator (gymnasium, random actions, resets) | {raw:.0f} | - | - | - |",
    ]
    for c, v in res["collect"].items():
        lines.append(
            f"| collection only, {c} collector (env + transforms + replay + stage buffers) | {v:.0f} ({v / raw:.2f}x raw) | - | - | - |"
        )
    for r in res["learn"]:
        ratio = f"{r['over_plain']:.2f}x" if "over_plain" in r else "-"
        same = f"{r['over_plain_same_updates']:.2f}x" if "over_plain_same_updates" in r else "-"
        lines.append(
            f"| phase 1, {r['algo']} (batch {r['batch_size']}, UTD {r['utd']:g}), {r['collector']} collector, "
            f"{r.get('precision', 'fp32')} | "
            f"{r['env_steps_per_s']:.1f} | {r['updates_per_s']:.1f} | {ratio} | {same} |"
        )
    for q in res["plain"]:
        spread = f" (before {q['before']:.1f}, after {q['after']:.1f})" if "before" in q else ""
        disc = f", {q['disc_updates']:g} discriminator steps per update" if q.get("disc_updates", 1) != 1 else ""
        who = f"; reference of {', '.join(q['reference_for'])}" if q.get("reference_for") else ""
        lines.append(
            f"| plain single-file PyTorch DrS loop (batch {q['batch_size']}, UTD {q.get('utd', 0.5):g}{disc}), fp32{who} | "
            f"{q['env_steps_per_s']:.1f}{spread} | {q['updates_per_s_overall']:.1f} | "
            f"{'1.00x' if _paper_settings(q) else '-'} | {'1.00x' if not _paper_settings(q) else '-'} |"
        )
    for c in res.get("components", []):
        lines += [
            "",
            f"Learner parts, {c['algo']} (batch {c['batch_size']}), ms per call:",
            "",
            f"- SAC update (sample, reward recomputation, loss, backward, Adam, target update): {c['sac_update_ms']:.1f} ms eager"
            + "".join(
                f", {ms:.1f} ms {p}" for p, ms in (c.get("sac_update_ms_by_precision") or {}).items() if p != "fp32"
            )
            + "".join(
                f", {c[f'sac_update_compiled{x}_ms']:.1f} ms with `algo.compile={scope}` (compiled in "
                f"{c[f'compile{x}_s']:.0f} s)"
                if f"sac_update_compiled{x}_ms" in c
                else f" (`algo.compile={scope}` failed: {c[f'compile{x}_error']})"
                if f"compile{x}_error" in c
                else ""
                for scope, x in (("loss", ""), ("update", "_whole"))
            ),
            f"- reward recomputation on one SAC batch (all discriminators, one pass): {c['reward_recompute_ms']:.2f} ms",
            f"- discriminator update (one batch per stage): {c['disc_update_ms']:.2f} ms",
            "",
            "| stage-buffer transitions | draw one discriminator batch (ms) | file a 50-step episode + draw (ms) |",
            "|---|---|---|",
        ]
        lines += [
            f"| {s['transitions']:,} | {s['sample_ms']:.3f} | {s['file_episode_and_sample_ms']:.3f} |"
            for s in c["stage_sample"]
        ]
    if res.get("roofline"):
        lines += [
            "",
            "Roofline: what this machine allows any implementation of the same algorithm "
            "(matrix products only, at the measured GEMM rate, perfect scaling, simulator fully overlapped):",
            "",
            "| config | precision | GFLOP per SAC update | GEMM GFLOP/s, 1 thread / all | update ms: bound (all cores) / measured | "
            "env steps/s bound | plain loop | bound / plain |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for r in res["roofline"]:
            gall = r[f"gemm_gflops_{r['cores']}_threads"]
            lines.append(
                f"| {r['algo']} (batch {r['batch_size']}, UTD {r['utd']}) | {r.get('precision', 'fp32')} | {r['gflop_per_update']:.2f} | "
                f"{r['gemm_gflops_1_thread']:.0f} / {gall:.0f} | {r['update_ms_lower_bound_all_cores']:.1f} / "
                f"{r['update_ms_measured']:.1f} | {r['env_steps_per_s_bound']:.1f} | "
                f"{r.get('plain_env_steps_per_s', float('nan')):.1f} | {r.get('bound_over_plain', float('nan')):.2f}x |"
            )
    if res.get("floor"):
        lines += [
            "",
            "Distance from the floor (goals: the update at most 1.5x its GEMM floor; the loop at least 0.7 of "
            "min(raw simulator, compute bound), or of their harmonic sum for the in-process collector):",
            "",
            "| row | precision | threads | measured | floor / limit | ratio |",
            "|---|---|---|---|---|---|",
        ]
        for f in res["floor"]:
            if f["what"] == "update":
                lines.append(
                    f"| SAC update, {f['algo']} | {f['precision']} | {f['threads']} | {f['measured_ms']:.2f} ms | "
                    f"{f['floor_ms']:.2f} ms (GEMM floor) | {f['over_floor']:.2f}x the floor |"
                )
            else:
                lines.append(
                    f"| phase-1 loop, {f['algo']}, {f['collector']} collector | {f['precision']} | {f['threads']} | "
                    f"{f['env_steps_per_s']:.1f} env steps/s | {f['limit_steps_per_s']:.1f} (raw "
                    f"{f['raw_sim_steps_per_s']:.0f}, compute bound {f['compute_bound_steps_per_s']:.0f}) | "
                    f"{f['of_limit']:.2f} of the limit |"
                )
    if "checkpoint" in res:
        c = res["checkpoint"]
        lines += [
            "",
            f"Training-state checkpoint of a run holding {c['transitions']:,} transitions (replay buffer and stage buffers "
            f"each): {c['bytes'] / 1e6:.0f} MB on disk, written in {c['write_s']:.1f} s, resumed (loaded) in {c['resume_s']:.1f} s.",
        ]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
