"""Numpy or torch actions into one CPU ManiSkill env: alternating blocks of random-action steps (README.md)."""

import time

import gymnasium as gym
import mani_skill.envs  # noqa: F401
import numpy as np
import torch

torch.set_num_threads(1)
env = gym.make(
    "PickCube-v1",
    obs_mode="state",
    control_mode="pd_ee_delta_pos",
    num_envs=1,
    sim_backend="physx_cpu",
    reward_mode="sparse",
    render_mode=None,
)
env.reset(seed=0)


def run(kind: str, n: int = 400) -> float:
    t = time.perf_counter()
    for _ in range(n):
        a = env.action_space.sample()
        if kind == "torch":  # what envs/maniskill.py hands ManiSkill: a (1, action) tensor
            a = torch.as_tensor(a).unsqueeze(0)
        _, _, term, trunc, _ = env.step(a)
        if bool((term | trunc).any()):
            env.reset()
    return n / (time.perf_counter() - t)


res = {"numpy": [], "torch": []}
for _ in range(4):
    for k in res:
        res[k].append(run(k))
for k, v in res.items():
    print(k, [round(x) for x in v], "median", round(float(np.median(v))))
