#!/usr/bin/env python
"""A/B timing of the batched-seeds lever: S seeds' SAC updates as S separate updates, or as one
update of TorchRL's ``SACLoss`` vmapped over S stacked parameter sets (one Adam over the stacked
tensors is S independent Adams: it is elementwise, and each seed's gradient comes from its own
loss only). For reference, one seed at batch S x 256: what a stacked update would cost if it were
as cheap as a larger batch. Variants alternate in blocks, so that load changes hit them alike.

    .venv/bin/python results/bench/batched_seeds/ab_batched_seeds.py --seeds 1 2 3 4 --json results/bench/batched_seeds/zen3_t1.json

The networks are the phase-2 SAC of ``algo=sac_cpu`` (MLP 256x3, twin critics one after the other)
at turn_valve's sizes (53 policy inputs, 9 actions), on synthetic batches: the update does not read
the values. Phase 2 has no discriminator step. Noise: ``torch.vmap(randomness="different")`` fails
inside torch.distributions' ``Normal.rsample`` (an in-place ``normal_`` on an unbatched tensor), so
the vmapped variant runs with ``randomness="same"`` (every seed draws the same actor noise): fine
for timing, not for independent seeds.
"""

import argparse
import json
import platform
import time

import torch
from tensordict import TensorDict
from torchrl.data import Bounded, Composite, Unbounded
from torchrl.objectives import SACLoss

from drs_torchrl.models import make_sac_modules


def make_loss(n_obs: int, n_act: int) -> SACLoss:
    obs_spec = Composite(observation=Unbounded(shape=(n_obs,)))
    act_spec = Bounded(-1.0, 1.0, shape=(n_act,))
    actor, qvalue = make_sac_modules(obs_spec, act_spec, ["observation"], [256, 256, 256])
    loss = SACLoss(
        actor, qvalue, num_qvalue_nets=2, loss_function="l2", alpha_init=1.0, action_spec=act_spec, deactivate_vmap=True
    )
    loss.make_value_estimator(gamma=0.8)
    return loss


def synthetic_batch(shape: tuple[int, ...], n_obs: int, n_act: int) -> TensorDict:
    false = torch.zeros(*shape, 1, dtype=torch.bool)
    return TensorDict(
        {
            "observation": torch.randn(*shape, n_obs),
            "action": torch.rand(*shape, n_act) * 2 - 1,
            ("next", "observation"): torch.randn(*shape, n_obs),
            ("next", "reward"): torch.randn(*shape, 1),
            ("next", "done"): false,
            ("next", "terminated"): false.clone(),
        },
        batch_size=shape,
    )


def total(out) -> torch.Tensor:
    return out["loss_actor"] + out["loss_qvalue"] + out["loss_alpha"]


def separate_updates(S: int, batch: int, n_obs: int, n_act: int):
    """S losses, optimisers and batches, updated one after the other (S runs' learners, serialised)."""
    losses = [make_loss(n_obs, n_act) for _ in range(S)]
    opts = [torch.optim.Adam(l.parameters(), lr=3e-4, fused=True) for l in losses]
    data = [synthetic_batch((batch,), n_obs, n_act) for _ in range(S)]

    def step():
        for loss, opt, d in zip(losses, opts, data):
            total(loss(d)).backward()
            opt.step()
            opt.zero_grad()

    return step


def vmapped_update(S: int, batch: int, n_obs: int, n_act: int):
    """One SACLoss evaluated under torch.vmap over S stacked parameter sets (and S batches)."""
    loss = make_loss(n_obs, n_act)
    params = (
        TensorDict.stack([TensorDict.from_module(make_loss(n_obs, n_act), as_module=False) for _ in range(S)])
        .detach()
        .clone()
    )
    trained = ("actor_network_params", "qvalue_network_params")
    leaves = [
        params[k].requires_grad_()
        for k in params.keys(True, True)
        if k == "log_alpha" or (isinstance(k, tuple) and k[0] in trained)
    ]
    opt = torch.optim.Adam(leaves, lr=3e-4, fused=True)
    data = synthetic_batch((S, batch), n_obs, n_act)

    def one_seed(p, d):
        with p.to_module(loss):
            return total(loss(d))

    losses = torch.vmap(one_seed, (0, 0), randomness="same")

    def step():
        losses(params, data).sum().backward()
        opt.step()
        opt.zero_grad()

    return step


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    p.add_argument("--batch", type=int, default=256)
    p.add_argument("--obs", type=int, default=53)
    p.add_argument("--act", type=int, default=9)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--reps", type=int, default=4)
    p.add_argument("--block", type=int, default=20)
    p.add_argument("--json", help="also write the results here")
    a = p.parse_args()
    torch.set_num_threads(a.threads)
    torch.manual_seed(0)
    rows = []
    for S in a.seeds:
        variants = {
            "separate": separate_updates(S, a.batch, a.obs, a.act),
            "vmapped": vmapped_update(S, a.batch, a.obs, a.act),
            "one seed, batch S x B": separate_updates(1, S * a.batch, a.obs, a.act),
        }
        for step in variants.values():
            for _ in range(3):
                step()
        ms = {k: [] for k in variants}
        for _ in range(a.reps):
            for k, step in variants.items():
                t = time.perf_counter()
                for _ in range(a.block):
                    step()
                ms[k].append((time.perf_counter() - t) / a.block * 1e3)
        row = {"seeds": S, **{f"ms_{k}": min(v) for k, v in ms.items()}, "blocks_ms": ms}
        row["speedup_vmapped"] = row["ms_separate"] / row["ms_vmapped"]
        row["speedup_bound"] = row["ms_separate"] / row["ms_one seed, batch S x B"]
        rows.append(row)
        print(
            f"S={S}: {S} separate updates {row['ms_separate']:.1f} ms, vmapped {row['ms_vmapped']:.1f} ms "
            f"({row['speedup_vmapped']:.2f}x), one seed at batch {S * a.batch} {row['ms_one seed, batch S x B']:.1f} ms "
            f"({row['speedup_bound']:.2f}x)",
            flush=True,
        )
    if a.json:
        with open(a.json, "w") as f:
            json.dump(
                {
                    "args": vars(a),
                    "machine": {"cpu": platform.processor() or platform.machine(), "torch": torch.__version__},
                    "results": rows,
                },
                f,
                indent=2,
            )


if __name__ == "__main__":
    main()
