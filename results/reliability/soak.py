#!/usr/bin/env python
"""A phase-1 run's training state at 1M transitions: memory, size, write time, resume, and a SIGKILL while writing.

    .venv/bin/python results/reliability/soak.py                 # -> results/reliability/soak.json and soak.md
    .venv/bin/python results/reliability/soak.py --transitions 100000 --out /tmp/soak   # smaller, elsewhere

A real PickCube phase-1 run (drs-learn defaults, one torch thread) collects 2048 real transitions and takes its
first updates; its replay buffer and stage buffers are then filled to ``--transitions`` each by tiling those
transitions (the buffer's memory and the state's bytes depend on how many transitions it holds, not on what they
are). Measured, in this order:

1. resident memory (this process) after each fill step, then over ``--updates`` SAC + discriminator updates with the
   buffers full: flat once full is the claim;
2. the training state's size on disk and its write time (``Run.save_training_state``);
3. a second process resumes that state and starts writing the next one; it is SIGKILLed once its temporary state
   directory holds about half the bytes; then the newest complete state must be the first one, intact, and a run
   resumes from it with every transition;
4. two independent resumes from that state take the same next updates (their losses and parameters are equal).

Not measured here: a run collecting 1M real env steps (3-7 hours on two cores); ``train.csv`` now logs ``rss_mib``
at every row, so such a run records its memory as it goes.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))


def rss_mib() -> float:
    from drs_torchrl.loop import resident_memory

    return round(resident_memory()["rss_mib"], 1)


def config(transitions: int):
    from hydra import compose, initialize_config_dir

    from drs_torchrl.apps.cli import conf_dir

    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        return compose(
            "learn",
            overrides=[
                "total_frames=2048",
                "algo.learning_starts=1024",
                "eval.episodes=0",
                "logger.progress_bar=false",
                "logger.tensorboard=false",
                "stop_at_success=null",
                f"algo.buffer_size={transitions}",
                f"reward.stage_buffer_size={transitions}",
                "checkpoint_interval=1000000000",
                "algo.collector._target_=torchrl.collectors.Collector",
                "torch_threads=1",
            ],
        )


def resumed(run_dir: Path, transitions: int):
    from drs_torchrl.apps.build import Run

    return Run(config(transitions), "learn", run_dir, resume=True)


def next_updates(run_dir: Path, transitions: int, n: int = 3) -> dict:
    """``n`` SAC + discriminator updates right after a resume: their losses and a digest of the parameters."""
    tr = resumed(run_dir, transitions)
    losses = []
    for _ in range(n):
        tr.learner.update()
        stats, _ = tr.updater.step()
        losses.append([float(stats[k]) for k in ("loss_actor", "loss_qvalue", "loss_alpha")])
    params = torch.cat([p.detach().reshape(-1) for p in tr.updater.loss.parameters()])
    tr.close()
    return {
        "losses": losses,
        "param_sum": float(params.double().sum()),
        "param_abs": float(params.double().abs().sum()),
    }


def child(run_dir: Path, transitions: int) -> None:
    """Resume and write the next state (the parent kills this process while it writes)."""
    tr = resumed(run_dir, transitions)
    print("resumed", flush=True)
    tr.save_training_state()
    tr.close()


def state_bytes(d: Path) -> int:
    return sum(f.stat().st_size for f in d.rglob("*") if f.is_file())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--transitions", type=int, default=1_000_000)
    ap.add_argument("--updates", type=int, default=400)
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "reliability")
    ap.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    a = ap.parse_args()
    torch.set_num_threads(1)
    from drs_torchrl.runtime.console import quiet_libraries

    quiet_libraries()
    if a.child:
        child(a.child, a.transitions)
        return 0
    from drs_torchrl.apps.build import Run
    from drs_torchrl.runtime.checkpoint import find_training_state

    res: dict = {
        "command": " ".join(["results/reliability/soak.py", *sys.argv[1:]]),
        "cpu": platform.processor() or platform.machine(),
        "transitions": a.transitions,
    }
    try:
        res["cpu"] = next(ln.split(":", 1)[1].strip() for ln in open("/proc/cpuinfo") if ln.startswith("model name"))
    except (OSError, StopIteration):
        pass
    d = Path(tempfile.mkdtemp(prefix="drs-soak-"))
    try:
        t0 = time.perf_counter()
        tr = Run(config(a.transitions), "learn", d)
        tr.run()
        tr = resumed(d, a.transitions)
        res["rss_after_real_run_mib"] = rss_mib()
        real = tr.updater.replay[: len(tr.updater.replay)].clone()
        states = torch.cat(tr.learner.stage_buffers.snapshot_parts())
        fill = []
        while len(tr.updater.replay) < a.transitions:
            tr.updater.replay.extend(real[: a.transitions - len(tr.updater.replay)])
            if len(tr.updater.replay) % (a.transitions // 10 or 1) < len(real):
                fill.append({"replay": len(tr.updater.replay), "rss_mib": rss_mib()})
        while len(tr.learner.stage_buffers) < a.transitions:
            tr.learner.stage_buffers.extend(states[: a.transitions - len(tr.learner.stage_buffers)])
        fill.append({"replay": len(tr.updater.replay), "stage": len(tr.learner.stage_buffers), "rss_mib": rss_mib()})
        res["fill"] = fill
        during = []
        for i in range(a.updates):
            tr.learner.update()
            tr.updater.step()
            tr.updater.replay.extend(real[:64])  # new transitions keep arriving: the full buffer overwrites its oldest
            if i % max(1, a.updates // 8) == 0 or i == a.updates - 1:
                during.append({"update": i + 1, "rss_mib": rss_mib()})
        res["updates_with_full_buffers"] = during
        t = time.perf_counter()
        state = tr.save_training_state()
        res["state_write_s"] = round(time.perf_counter() - t, 2)
        res["state_bytes"] = state_bytes(state)
        res["state_bytes_per_transition"] = round(res["state_bytes"] / a.transitions, 1)
        first_complete = (state / "COMPLETE").read_text()
        tr.close()
        del tr, real, states

        # SIGKILL while the next state is being written
        env = dict(os.environ, PYTHONPATH=str(ROOT / "src"), OMP_NUM_THREADS="1")
        proc = subprocess.Popen(
            [sys.executable, __file__, "--child", str(d), "--transitions", str(a.transitions)],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
        )
        for line in proc.stdout:  # the run's own notes first
            if line.strip() == "resumed":
                break
        killed_at, t = None, time.perf_counter()
        while proc.poll() is None and time.perf_counter() - t < 600:
            tmp = list((d / "checkpoints").glob("state.tmp-*"))
            if tmp and state_bytes(tmp[0]) > res["state_bytes"] // 2:
                killed_at = state_bytes(tmp[0])
                proc.send_signal(signal.SIGKILL)
                break
            time.sleep(0.01)
        proc.wait(60)
        kept = find_training_state(d)
        res["sigkill_during_write"] = {
            "killed_with_bytes_written": killed_at,
            "exit": proc.returncode,
            "newest_complete_state": kept.name,
            "same_state_as_before": (kept / "COMPLETE").read_text() == first_complete,
            "partial_left": [p.name for p in (d / "checkpoints").glob("state.tmp-*")],
        }
        t = time.perf_counter()
        tr = resumed(d, a.transitions)
        res["resume_s"] = round(time.perf_counter() - t, 2)
        res["resumed_transitions"] = {"replay": len(tr.updater.replay), "stage": len(tr.learner.stage_buffers)}
        res["rss_after_resume_mib"] = rss_mib()
        tr.close()
        del tr
        first, second = next_updates(d, a.transitions), next_updates(d, a.transitions)
        res["two_resumes_take_the_same_next_updates"] = first == second
        res["next_updates"] = first
        res["wall_s"] = round(time.perf_counter() - t0, 1)
    finally:
        shutil.rmtree(d, ignore_errors=True)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "soak.json").write_text(json.dumps(res, indent=1) + "\n")
    k = res["sigkill_during_write"]
    flat = [r["rss_mib"] for r in res["updates_with_full_buffers"]]
    md = [
        f"# Training state at {a.transitions:,} transitions (`{res['command']}`)",
        "",
        f"Machine: {res['cpu']}, one torch thread. Wall time {res['wall_s']} s. Raw numbers: `soak.json`.",
        "",
        "| measure | value |",
        "|---|---|",
        f"| resident memory after the 2048-step real run | {res['rss_after_real_run_mib']} MiB |",
        f"| ... with replay and stage buffers full ({a.transitions:,} each) | {res['fill'][-1]['rss_mib']} MiB |",
        f"| ... over {a.updates} updates with full buffers (new transitions overwriting) | "
        f"{min(flat)}-{max(flat)} MiB (first {flat[0]}, last {flat[-1]}) |",
        f"| training state on disk | {res['state_bytes'] / 2**20:.0f} MiB ({res['state_bytes_per_transition']} bytes "
        "per transition, replay + stage buffers) |",
        f"| its write time | {res['state_write_s']} s |",
        f"| SIGKILL while the next state was written ({(k['killed_with_bytes_written'] or 0) / 2**20:.0f} MiB in) | "
        f"newest complete state: `{k['newest_complete_state']}`, the one before: {k['same_state_as_before']}; "
        f"partial left: {k['partial_left'] or 'none'} (removed by the next save) |",
        f"| resume from it | {res['resume_s']} s, {res['resumed_transitions']['replay']:,} replay and "
        f"{res['resumed_transitions']['stage']:,} stage transitions |",
        f"| two resumes take the same next 3 updates | {res['two_resumes_take_the_same_next_updates']} |",
        "",
    ]
    (a.out / "soak.md").write_text("\n".join(md))
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    sys.exit(main())
