#!/usr/bin/env python
"""Where the SAC update's time goes beyond its matrix products (issue 64, item 1), on synthetic PickCube-shaped data
(no simulator; `compile_probe.build`: the pipeline's updater, `algo=sac_cpu`'s loss, fused Adam, target update).

Two measurements, each alternated in blocks so that the machine's load hits both sides alike:
* **size-independent overhead**: the same update with 256-wide and with 8-wide hidden layers. The 8-wide one does
  almost no arithmetic, so its time is what every update pays whatever its size (Python, TensorDict and TorchRL
  bookkeeping, dispatch, the small ops); its share of the 256-wide update is the part no faster GEMM can remove.
* **what torch.compile removes**: the loss's forward pass (without, then with its backward), eager against
  `torch.compile`d, at both widths (twin critics vmapped: the one-graph case, `compile_probe/`), so that one can see
  whether compiling removes the overhead (8-wide) and what it does to the matrix products (256-wide).

    .venv/bin/python results/bench/overhead_probe.py --note "idle" --out results/bench/overhead_probe
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from compile_probe import ROOT, build, whole_update  # noqa: E402


def blocks(fns: dict, batches: list, reps: int, n: int) -> dict[str, list[float]]:
    """ms per call of each function, ``reps`` blocks of ``n`` calls, alternated."""
    for fn in fns.values():
        for b in batches[:3]:
            fn(b)
    out = {k: [] for k in fns}
    for _ in range(reps):
        for k, fn in fns.items():
            t = time.perf_counter()
            for i in range(n):
                fn(batches[i % len(batches)])
            out[k].append((time.perf_counter() - t) / n * 1e3)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--n", type=int, default=40)
    ap.add_argument("--note", default="", help="what else ran on the machine")
    ap.add_argument("--mode", default=None, help="torch.compile mode (e.g. max-autotune-no-cudagraphs)")
    ap.add_argument("--backend", default="inductor", help="torch.compile backend (aot_eager: traced, eager kernels)")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "bench" / "overhead_probe")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    from drs_torchrl.runtime.console import quiet_libraries

    quiet_libraries()
    cpu = next((ln.split(":", 1)[1].strip() for ln in open("/proc/cpuinfo") if ln.startswith("model name")), "?")
    # the pipeline's update (critics one after the other, as conf/algo/sac_cpu.yaml), 256 and 8 wide
    wide, narrow = build(True, False, 256), build(True, False, 8)
    batches = [wide.sample() for _ in range(8)]
    # and the same 256-wide update with its loss compiled (critics vmapped: one graph), the decision's comparison
    vmapped = build(True, True, 256)
    vmapped.loss = torch.compile(vmapped.loss, mode=a.mode, backend=a.backend)
    upd = blocks(
        {
            "256 wide": whole_update(wide),
            "8 wide": whole_update(narrow),
            "256 wide, loss compiled": whole_update(vmapped),
        },
        batches,
        a.reps,
        a.n,
    )
    # the loss's forward, eager and compiled (vmapped critics: one graph, no recompilation)
    fwd = {}
    for h in (256, 8):
        u = build(True, True, h)
        compiled = torch.compile(u.loss, mode=a.mode, backend=a.backend)
        t = time.perf_counter()
        with torch.no_grad():
            compiled(batches[0])
        compile_s = time.perf_counter() - t
        with torch.no_grad():
            ms = blocks({"eager": u.loss, "compiled": compiled}, batches, a.reps, a.n)

        def train(loss):
            def step(b):
                out = loss(b)
                (out["loss_actor"] + out["loss_qvalue"] + out["loss_alpha"]).backward()

            return step

        ms |= blocks(
            {"eager, with backward": train(u.loss), "compiled, with backward": train(compiled)}, batches, a.reps, a.n
        )
        fwd[h] = {"compile_s": round(compile_s, 1), **{k: [round(x, 2) for x in v] for k, v in ms.items()}}
    best = {k: min(v) for k, v in upd.items()}
    res = {
        "command": " ".join(["results/bench/overhead_probe.py", *sys.argv[1:]]),
        "cpu": cpu,
        "platform": platform.platform(),
        "torch": torch.__version__,
        "threads": a.threads,
        "note": a.note,
        "compile_mode": a.mode,
        "compile_backend": a.backend,
        "update_ms": {k: [round(x, 2) for x in v] for k, v in upd.items()},
        "overhead_share": round(best["8 wide"] / best["256 wide"], 3),
        "loss_forward_ms": fwd,
    }
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "overhead_probe.json").write_text(json.dumps(res, indent=1) + "\n")
    md = [
        f"# The SAC update's size-independent overhead, and what torch.compile removes (`{res['command']}`)",
        "",
        f"{cpu}, torch {res['torch']}, {a.threads} thread(s), compile backend {a.backend}, mode {a.mode or 'default'}. {a.note}",
        "",
        "| measurement | ms per call, each block (min) |",
        "|---|---|",
    ]
    for k, v in upd.items():
        how = "critics vmapped, the loss compiled" if "compiled" in k else "eager; critics one after the other"
        md.append(f"| whole update, hidden {k} ({how}) | {', '.join(f'{x:.1f}' for x in v)} ({min(v):.1f}) |")
    for h, r in fwd.items():
        for k in ("eager", "compiled", "eager, with backward", "compiled, with backward"):
            md.append(
                f"| loss forward, hidden {h} wide, {k} (vmapped critics) | "
                f"{', '.join(f'{x:.1f}' for x in r[k])} ({min(r[k]):.1f}) |"
            )
    md += [
        "",
        f"Size-independent share of the 256-wide update: **{res['overhead_share']:.2f}** (8-wide min / 256-wide min). "
        f"Compilation took {fwd[256]['compile_s']} s (256 wide) and {fwd[8]['compile_s']} s (8 wide).",
    ]
    (a.out / "overhead_probe.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    sys.exit(main())
