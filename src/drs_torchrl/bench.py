"""``drs-bench``: measured speeds of the pipeline on this machine, in one run.

Measures, on the same task and machine:
  * ``raw_sim``: ManiSkill's gymnasium env stepped with random actions (with resets);
  * ``collect``: the TorchRL pipeline without learning: Collector + ManiSkillEnv + StageIndicator,
    random policy, transitions into the replay buffer, episodes assembled and filed into the stage
    buffers;
  * ``learn_<algo>``: phase 1 (SAC + discriminators, UTD of the config) after learning starts,
    env steps/s and gradient updates/s, for each algo config given;
  * ``plain``: the same algorithm as a plain single-file PyTorch loop (``drs_torchrl.plain_loop``)
    at each config's batch size, side by side, and the pipeline's speed ratio over it.

Writes ``results/bench/bench.json`` and ``results/bench/bench.md``. Usage::

    drs-bench                       # PickCube, sac_cpu and sac_paper
    drs-bench --learn-frames 2048 --algos sac_cpu
"""
from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import torch


def bench_raw_sim(env_id: str, steps: int, env_kwargs: dict, control_mode: str) -> float:
    import gymnasium as gym
    import mani_skill.envs  # noqa: F401

    import drs_torchrl.envs.variants  # noqa: F401

    env = gym.make(env_id, obs_mode="state", control_mode=control_mode, num_envs=1, sim_backend="physx_cpu",
                   reward_mode="sparse", render_mode=None, **env_kwargs)
    env.reset(seed=0)
    t = time.perf_counter()
    for _ in range(steps):
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        if bool((term | trunc).any()):
            env.reset()
    dt = time.perf_counter() - t
    env.close()
    return steps / dt


def bench_collect(family, steps: int) -> float:
    from torchrl.collectors import Collector
    from torchrl.data import LazyTensorStorage, ReplayBuffer

    from drs_torchrl.data import StageBuffers, TrajectoryAssembler
    from drs_torchrl.envs.factory import make_family_env

    env = make_family_env(family, "train", seed=0)
    rb = ReplayBuffer(storage=LazyTensorStorage(steps + 64))
    sb = StageBuffers(family.num_stages, list(family.reward_in_keys), capacity=steps + 64)
    asm = TrajectoryAssembler()
    collector = Collector(env, None, frames_per_batch=64, total_frames=steps, auto_register_policy_transforms=False)
    t = time.perf_counter()
    n = 0
    for batch in collector:
        rb.extend(batch.reshape(-1))
        for ep in asm.add(batch):
            sb.add_trajectory(ep)
        n += batch.numel()
    dt = time.perf_counter() - t
    collector.shutdown()
    env.close()
    return n / dt


def bench_learn(algo: str, frames: int, overrides: list[str]) -> dict:
    """Phase-1 speed after learning starts: env steps/s and updates/s over ``frames`` steps."""
    import tempfile

    from hydra import compose, initialize_config_dir

    from drs_torchrl.trainers.apps import conf_dir
    from drs_torchrl.trainers.loop import Trainer

    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        cfg = compose("learn", overrides=[f"algo={algo}", *overrides])
    start = int(cfg.algo.learning_starts)
    cfg.total_frames = start + frames
    cfg.eval.interval = 10**9
    cfg.eval.episodes = 0
    cfg.checkpoint_interval = 10**9
    cfg.logger.progress_bar = False
    cfg.logger.tensorboard = False
    cfg.logger.interval = frames  # one row for the warm-up, one for the timed part
    with tempfile.TemporaryDirectory() as d:
        tr = Trainer(cfg, "learn", d)
        # fill the warm-up without timing it
        tr.run()
        import csv

        rows = list(csv.DictReader(open(Path(d) / "train.csv")))
    timed = [r for r in rows if float(r["frames"]) > start]
    r = timed[-1]
    return {
        "algo": algo,
        "batch_size": int(cfg.algo.batch_size),
        "utd": float(cfg.algo.utd),
        "frames_timed": frames,
        "env_steps_per_s": float(r["env_steps_per_s"]),
        "updates_per_s": float(r["updates_per_s"]),
        "collect_steps_per_s_within_learning": float(r["collect_steps_per_s"]),
    }


def bench_checkpoint(transitions: int) -> dict:
    """Size and write/read time of the training state of a run holding ``transitions`` transitions.

    A real phase-1 Trainer (PickCube) collects 1024 real transitions; they are tiled until the
    replay buffer and the stage buffers each hold ``transitions``; then the state is saved (timed),
    and a second Trainer resumes from it (timed).
    """
    import shutil
    import tempfile

    from hydra import compose, initialize_config_dir

    from drs_torchrl.trainers.apps import conf_dir
    from drs_torchrl.trainers.loop import Trainer

    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        cfg = compose("learn", overrides=["total_frames=1024", "algo.learning_starts=100000", "eval.episodes=0",
                                          "logger.progress_bar=false", "logger.tensorboard=false",
                                          f"algo.buffer_size={transitions}", f"reward.stage_buffer_size={transitions}",
                                          "checkpoint_interval=1000000000"])
    d = Path(tempfile.mkdtemp(prefix="drs-ckpt-"))
    try:
        tr = Trainer(cfg, "learn", d)
        tr.run()  # 1024 real transitions, saved state included
        tr = Trainer(cfg, "learn", d, resume=True)
        real = tr.replay[: len(tr.replay)].clone()
        states = torch.cat(tr.stage_buffers.snapshot_parts())
        while len(tr.replay) < transitions:
            tr.replay.extend(real[: transitions - len(tr.replay)])
        while len(tr.stage_buffers) < transitions:
            tr.stage_buffers.extend(states[: transitions - len(tr.stage_buffers)])
        t = time.perf_counter()
        state = tr.save_training_state()
        write_s = time.perf_counter() - t
        size = sum(f.stat().st_size for f in state.rglob("*") if f.is_file())
        tr.close()
        t = time.perf_counter()
        tr2 = Trainer(cfg, "learn", d, resume=True)
        read_s = time.perf_counter() - t
        ok = len(tr2.replay) == transitions and len(tr2.stage_buffers) == transitions
        tr2.close()
    finally:
        shutil.rmtree(d, ignore_errors=True)
    return {"transitions": transitions, "bytes": size, "write_s": write_s, "resume_s": read_s, "restored": ok,
            "bytes_per_transition_replay_plus_stage": size / transitions}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="drs-bench", description=__doc__.split("\n")[0])
    p.add_argument("--family", default="pick_cube")
    p.add_argument("--raw-steps", type=int, default=3000)
    p.add_argument("--collect-steps", type=int, default=3008)
    p.add_argument("--learn-frames", type=int, default=2048)
    p.add_argument("--algos", nargs="*", default=["sac_cpu", "sac_paper"])
    p.add_argument("--out", default="results/bench")
    p.add_argument("--no-plain", action="store_true", help="skip the plain single-file loop baseline")
    p.add_argument("--checkpoint", type=int, default=0, metavar="N",
                   help="also measure the training-state checkpoint of a run holding N transitions (e.g. 1000000)")
    a = p.parse_args(argv)
    from drs_torchrl.tasks import get_family

    fam = get_family(a.family)
    kw = fam.variant_kwargs("train")
    res: dict = {
        "command": "drs-bench " + " ".join(sys.argv[1:] if argv is None else argv),
        "machine": {"cpus": torch.get_num_threads(), "platform": platform.platform(), "torch": torch.__version__,
                    "cuda": torch.cuda.is_available()},
        "family": a.family,
    }
    print("raw simulator ...", flush=True)
    res["raw_sim_steps_per_s"] = bench_raw_sim(fam.env_id, a.raw_steps, kw, fam.control_mode)
    print(f"  {res['raw_sim_steps_per_s']:.0f} steps/s\ncollection only ...", flush=True)
    res["collect_steps_per_s"] = bench_collect(fam, a.collect_steps)
    print(f"  {res['collect_steps_per_s']:.0f} steps/s", flush=True)
    res["learn"] = []
    for algo in a.algos:
        print(f"phase 1, {algo} ...", flush=True)
        r = bench_learn(algo, a.learn_frames, [f"env.family={a.family}"])
        res["learn"].append(r)
        print(f"  {r['env_steps_per_s']:.1f} env steps/s, {r['updates_per_s']:.1f} updates/s", flush=True)
    res["plain"] = []
    if not a.no_plain:
        from drs_torchrl.plain_loop import run_plain_drs

        for r in res["learn"]:
            print(f"plain single-file loop, batch {r['batch_size']} ...", flush=True)
            q = run_plain_drs(fam.env_id, kw, fam.stage_keys, r["batch_size"], a.learn_frames)
            q["pipeline_over_plain"] = r["env_steps_per_s"] / q["env_steps_per_s"]
            res["plain"].append(q)
            print(f"  {q['env_steps_per_s']:.1f} env steps/s (pipeline {q['pipeline_over_plain']:.2f}x)", flush=True)
    if a.checkpoint:
        print(f"checkpoint of a {a.checkpoint}-transition run ...", flush=True)
        res["checkpoint"] = c = bench_checkpoint(a.checkpoint)
        print(f"  {c['bytes'] / 1e6:.0f} MB, written in {c['write_s']:.1f}s, resumed in {c['resume_s']:.1f}s", flush=True)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench.json").write_text(json.dumps(res, indent=2))
    lines = [
        f"# drs-bench on {a.family}", "", f"Command: `{res['command']}`", "",
        f"Machine: {res['machine']['cpus']} torch threads, {res['machine']['platform']}, torch {res['machine']['torch']}, CUDA {res['machine']['cuda']}", "",
        "| measurement | env steps/s | updates/s |", "|---|---|---|",
        f"| raw simulator (gymnasium, random actions, resets) | {res['raw_sim_steps_per_s']:.0f} | - |",
        f"| collection only (Collector + transforms + replay + stage buffers) | {res['collect_steps_per_s']:.0f} | - |",
    ]
    for r in res["learn"]:
        lines.append(f"| phase 1, {r['algo']} (batch {r['batch_size']}, UTD {r['utd']}) | {r['env_steps_per_s']:.1f} | {r['updates_per_s']:.1f} |")
    for q in res["plain"]:
        lines.append(f"| plain single-file PyTorch DrS loop, same algorithm (batch {q['batch_size']}, UTD 0.5) | "
                     f"{q['env_steps_per_s']:.1f} | - |")
    if res["plain"]:
        lines += ["", "Pipeline over the plain loop, phase-1 env steps/s at the same config: " + ", ".join(
            f"batch {q['batch_size']}: {q['pipeline_over_plain']:.2f}x" for q in res["plain"]) + "."]
    if "checkpoint" in res:
        c = res["checkpoint"]
        lines += ["", f"Training-state checkpoint of a run holding {c['transitions']:,} transitions (replay buffer and stage buffers "
                  f"each): {c['bytes'] / 1e6:.0f} MB on disk, written in {c['write_s']:.1f} s, resumed (loaded) in {c['resume_s']:.1f} s."]
    (out / "bench.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
