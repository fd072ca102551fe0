"""Measure the runnable task families on this machine (single CPU env, random policy).

For each family: observation / action sizes of both splits, env steps/s through the TorchRL env
(random actions, episodes reset at their time limit), the cost of a reset with per-episode
variant sampling (the split's pool) against a reset of a one-variant env and against a ManiSkill
reconfiguration (what rebuilding the scene per variant would cost), and the random policy's stage
reach rates. Writes measure.json beside this file.

    .venv/bin/python results/families/measure.py [family ...]
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import torch

torch.set_num_threads(1)

from drs_torchrl.envs import make_family_env  # noqa: E402
from drs_torchrl.tasks import get_family  # noqa: E402

RUNNABLE = ["pick_cube", "pick_and_place", "turn_valve", "stack_cube", "place_sphere", "cross_robot"]


def reset_ms(env, n=200) -> float:
    env.reset()
    t = time.perf_counter()
    for _ in range(n):
        env.reset()
    return (time.perf_counter() - t) / n * 1e3


def reconfigure_ms(env, n=10) -> float:
    u = env.base_env.unwrapped
    t = time.perf_counter()
    for _ in range(n):
        u.reset(options={"reconfigure": True})
    return (time.perf_counter() - t) / n * 1e3


def measure(name: str) -> dict:
    fam = get_family(name)
    out = {"family": name, "env_id": fam.env_id, "stages": list(fam.stage_keys)}
    t = time.perf_counter()
    env = make_family_env(fam, "train", seed=0)
    out["build_s"] = round(time.perf_counter() - t, 2)
    test = make_family_env(fam, "test", seed=0)
    for split, e in (("train", env), ("test", test)):
        out[f"{split}_obs"] = int(e.observation_spec["observation"].shape[-1])
        out[f"{split}_act"] = int(e.action_spec.shape[-1])
        if fam.task_observation_key:
            out[f"{split}_task_obs"] = int(e.observation_spec[fam.task_observation_key].shape[-1])
    test.close()
    steps = 20 * fam.max_episode_steps
    env.rollout(50, break_when_any_done=False)  # warm-up
    t = time.perf_counter()
    td = env.rollout(steps, break_when_any_done=False)
    out["steps_per_s"] = round(steps / (time.perf_counter() - t), 1)
    # random policy: share of episodes that reached each stage (an episode's stage is its highest)
    done = td["next", "done"].reshape(-1)
    stage = td["next", "stage"].reshape(-1)
    ends = done.nonzero().reshape(-1).tolist()
    starts = [0] + [e + 1 for e in ends[:-1]]
    best = torch.tensor([int(stage[s : e + 1].max()) for s, e in zip(starts, ends)])
    out["random_episodes"] = len(ends)
    out["random_reach"] = {k: round(float((best >= i + 1).float().mean()), 3) for i, k in enumerate(fam.stage_keys)}
    out["variants_seen"] = sorted({env.base_env.variant_names[int(i)] for i in td["next", "variant_index"].reshape(-1)})
    # reset costs
    out["reset_ms_pool"] = round(reset_ms(env), 2)
    one = make_family_env(fam, fam.train_variants[0], seed=0)
    out["reset_ms_one_variant"] = round(reset_ms(one), 2)
    out["reset_ms_reconfigure"] = round(reconfigure_ms(one), 1)
    one.close()
    env.close()
    return out


if __name__ == "__main__":
    names = sys.argv[1:] or RUNNABLE
    path = Path(__file__).with_name("measure.json")
    results = json.loads(path.read_text()) if path.exists() else {}
    for n in names:
        r = measure(n)
        print(json.dumps(r), flush=True)
        results[n] = r
        path.write_text(json.dumps(results, indent=1))
