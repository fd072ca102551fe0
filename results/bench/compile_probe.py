#!/usr/bin/env python
"""What ``torch.compile`` makes of the whole SAC update on this CPU (issue 64, item 1): graphs, graph breaks and
recompilations (with their reasons) over many updates, and the ms of an eager and a compiled update on the same
batches. No simulator: the pipeline's SAC updater (`algo=sac_cpu`'s networks, loss, fused Adam, target update) on a
replay buffer of synthetic PickCube-shaped transitions.

    .venv/bin/python results/bench/compile_probe.py --out results/bench/compile_probe       # compile_probe.{json,md}

The counts do not depend on the machine's load; the ms do (say what else ran).
"""

from __future__ import annotations

import argparse
import functools
import json
import platform
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))


def build(fused: bool, vmap: bool, hidden: int = 256):
    from tensordict import TensorDict
    from torchrl.data import Bounded, Composite, LazyTensorStorage, ReplayBuffer, Unbounded
    from torchrl.objectives import SACLoss, SoftUpdate

    from drs_torchrl.updaters.sac import make_sac_updater

    class Env:
        observation_spec = Composite(observation=Unbounded((42,)), stage_indicators=Unbounded((3,)))
        action_spec = Bounded(-1.0, 1.0, (8,))

    g = torch.Generator().manual_seed(0)
    n = 20_000
    nxt = {
        "observation": torch.randn(n, 42, generator=g),
        "stage_indicators": torch.rand(n, 3, generator=g).round(),
        "reward": torch.randn(n, 1, generator=g),
        "done": torch.zeros(n, 1, dtype=torch.bool),
        "terminated": torch.zeros(n, 1, dtype=torch.bool),
    }
    data = {"observation": torch.randn(n, 42, generator=g), "stage_indicators": torch.rand(n, 3, generator=g).round()}
    data.update(action=torch.rand(n, 8, generator=g) * 2 - 1, next=nxt)
    rb = ReplayBuffer(storage=LazyTensorStorage(n), batch_size=256)
    rb.extend(TensorDict(data, [n]))
    torch.manual_seed(0)
    loss = functools.partial(SACLoss, num_qvalue_nets=2, loss_function="l2", alpha_init=1.0, deactivate_vmap=not vmap)
    return make_sac_updater(
        Env(), rb, loss=loss, optim=functools.partial(torch.optim.Adam, lr=3e-4, fused=fused),
        target_update=functools.partial(SoftUpdate, tau=0.005), hidden=[hidden] * 3,
        policy_in_keys=["observation", "stage_indicators"], gamma=0.8, utd=0.5, learning_starts=0,
    )  # fmt: skip


def whole_update(u):
    """Loss, backward, the three optimiser steps and the target update: what a compiled step would hold."""
    opts = list(u.optimizers.values())

    def update(sample):
        out = u.loss(sample)
        total = out["loss_actor"] + out["loss_qvalue"] + out["loss_alpha"]
        for o in opts:
            o.zero_grad(set_to_none=True)
        total.backward()
        for o in opts:
            o.step()
        u.target_updater.step()
        return total.detach()

    return update


def probe(fused: bool, vmap: bool, updates: int) -> dict:
    import torch._dynamo
    from torch._dynamo.utils import counters

    torch._dynamo.reset()
    counters.clear()
    u = build(fused, vmap)
    batches = [u.sample() for _ in range(8)]
    update = whole_update(u)
    compiled = torch.compile(update)
    t = time.perf_counter()
    compiled(batches[0])
    first_s = time.perf_counter() - t
    graphs_first = int(counters["stats"]["unique_graphs"])
    for i in range(updates):
        compiled(batches[i % len(batches)])
    graphs = int(counters["stats"]["unique_graphs"])
    breaks = {k.split("\n")[0][:160]: v for k, v in counters["graph_break"].items()}

    def ms(fn, n=30):
        for b in batches[:3]:
            fn(b)
        t = time.perf_counter()
        for i in range(n):
            fn(batches[i % len(batches)])
        return (time.perf_counter() - t) / n * 1e3

    eager_ms, compiled_ms = [], []
    for _ in range(3):  # alternated: the same load on both
        eager_ms.append(ms(update))
        compiled_ms.append(ms(compiled))
    return {
        "fused_adam": fused,
        "vmap": vmap,
        "first_call_s": round(first_s, 1),
        "graphs_after_first_call": graphs_first,
        "graphs_after_all": graphs,
        "frames": dict(counters["frames"]),
        "graph_breaks": breaks,
        "eager_ms": [round(x, 2) for x in eager_ms],
        "compiled_ms": [round(x, 2) for x in compiled_ms],
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--updates", type=int, default=50)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--note", default="", help="what else ran on the machine")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "bench" / "compile_probe")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    from drs_torchrl.runtime.console import quiet_libraries

    quiet_libraries()
    cpu = next((ln.split(":", 1)[1].strip() for ln in open("/proc/cpuinfo") if ln.startswith("model name")), "?")
    res = {
        "command": " ".join(["results/bench/compile_probe.py", *sys.argv[1:]]),
        "cpu": cpu,
        "platform": platform.platform(),
        "torch": torch.__version__,
        "threads": a.threads,
        "note": a.note,
        # deactivate_vmap=True is the pipeline's choice (faster eager at one thread, and autocast reaches the critics)
        "runs": [probe(fused, vmap, a.updates) for vmap in (False, True) for fused in (True, False)],
    }
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "compile_probe.json").write_text(json.dumps(res, indent=1) + "\n")
    md = [
        f"# torch.compile of the whole SAC update (`{res['command']}`)",
        "",
        f"{cpu}, torch {res['torch']}, {a.threads} thread(s). {a.note}",
        "",
        "| twin critics | Adam | first call (compile) | graphs after it / after all updates | graph breaks (reason: count) "
        "| eager ms | compiled ms |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in res["runs"]:
        breaks = "; ".join(f"{k}: {v}" for k, v in r["graph_breaks"].items()) or "none"
        md.append(
            f"| {'vmap' if r['vmap'] else 'one after the other'} | {'fused' if r['fused_adam'] else 'foreach'} | "
            f"{r['first_call_s']} s | {r['graphs_after_first_call']} / {r['graphs_after_all']} | {breaks} | "
            f"{', '.join(map(str, r['eager_ms']))} | {', '.join(map(str, r['compiled_ms']))} |"
        )
    (a.out / "compile_probe.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    sys.exit(main())
