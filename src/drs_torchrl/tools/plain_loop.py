"""A plain single-file PyTorch DrS loop, as a speed baseline for ``drs-bench`` (not used for training).

The same algorithm and networks as the TorchRL pipeline (SAC with twin 3x256 critics, tanh-Gaussian
actor, auto-tuned entropy; one 32-unit sigmoid discriminator per stage; rewards recomputed on every
SAC batch; UTD 0.5, training every 64 steps), written the way a researcher would write it by hand:
gymnasium env, numpy buffers, sequential collect-then-train, no TensorDict. ``drs-bench`` runs it
beside the pipeline so the two are compared in one run on one machine.
"""

from __future__ import annotations

import time

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn


def _mlp(i, o, h=(256, 256, 256)):
    layers, d = [], i
    for w in h:
        layers += [nn.Linear(d, w), nn.ReLU()]
        d = w
    return nn.Sequential(*layers, nn.Linear(d, o))


def run_plain_drs(
    env_id: str,
    env_kwargs: dict,
    stage_keys,
    batch_size: int,
    timed_frames: int,
    learning_starts: int = 4000,
    train_every: int = 64,
    utd: float = 0.5,
    gamma: float = 0.8,
    tau: float = 0.005,
    seed: int = 0,
    disc_updates: float = 1,
    disc_batch_size: int | None = None,
) -> dict:
    """Run the loop for ``learning_starts + timed_frames`` steps; returns env steps/s and updates/s
    over the timed (learning) part. ``disc_updates``: discriminator steps per SAC update; ``disc_batch_size``: per side (default: the SAC batch)."""
    import gymnasium as gym
    import mani_skill.envs  # noqa: F401

    import drs_torchrl.envs.variants  # noqa: F401

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    env = gym.make(
        env_id,
        obs_mode="state",
        control_mode="pd_ee_delta_pos",
        num_envs=1,
        sim_backend="physx_cpu",
        reward_mode="sparse",
        render_mode=None,
        **env_kwargs,
    )
    N = len(stage_keys)
    db = int(disc_batch_size or batch_size)
    act_dim = env.action_space.shape[-1]

    def observe(obs, info):  # state + monotone stage indicators, as the authors append them
        ind = np.array([bool(info[k]) for k in stage_keys], dtype=np.float32)
        mono = np.maximum.accumulate(ind[::-1])[::-1]
        return np.concatenate([np.asarray(obs, dtype=np.float32).reshape(-1), mono]), int(mono.sum())

    obs, info = env.reset(seed=seed)
    o, _ = observe(obs, info)
    obs_dim = o.size
    actor, q1, q2 = _mlp(obs_dim, 2 * act_dim), _mlp(obs_dim + act_dim, 1), _mlp(obs_dim + act_dim, 1)
    q1_t, q2_t = _mlp(obs_dim + act_dim, 1), _mlp(obs_dim + act_dim, 1)
    q1_t.load_state_dict(q1.state_dict())
    q2_t.load_state_dict(q2.state_dict())
    disc = nn.ModuleList(nn.Sequential(nn.Linear(obs_dim, 32), nn.Sigmoid(), nn.Linear(32, 1)) for _ in range(N))
    log_alpha = torch.zeros(1, requires_grad=True)
    opt_a = torch.optim.Adam(actor.parameters(), 3e-4)
    opt_q = torch.optim.Adam([*q1.parameters(), *q2.parameters()], 3e-4)
    opt_al = torch.optim.Adam([log_alpha], 3e-4)
    opt_d = torch.optim.Adam(disc.parameters(), 3e-4)
    total = learning_starts + timed_frames
    cap = total + train_every  # collection runs in rounds of train_every steps
    B_obs, B_act = np.zeros((cap, obs_dim), np.float32), np.zeros((cap, act_dim), np.float32)
    B_next, B_stage, B_term = np.zeros((cap, obs_dim), np.float32), np.zeros(cap, np.int64), np.zeros(cap, np.float32)
    stage_bufs = [[] for _ in range(N + 1)]
    ep_next, ep_stage = [], []

    def policy(x):
        mu, log_std = actor(x).chunk(2, -1)
        std = log_std.clamp(-5, 2).exp()
        u = mu + std * torch.randn_like(mu)
        a = torch.tanh(u)
        logp = (torch.distributions.Normal(mu, std).log_prob(u) - torch.log(1 - a.pow(2) + 1e-6)).sum(-1, keepdim=True)
        return a, logp

    def reward(next_obs, stage):
        with torch.no_grad():
            logits = torch.cat([d(next_obs) for d in disc], -1)
            dense = torch.tanh(logits.gather(-1, stage.clamp(max=N - 1)[:, None])).squeeze(-1)
            dense = torch.where(stage < N, dense, torch.zeros_like(dense))
            return (stage.float() + dense / 3) / N - 2

    def sample_stages(lo, hi, n):
        pool = [np.concatenate(stage_bufs[j]) for j in range(lo, hi) if stage_bufs[j]]
        if not pool:
            return None
        pool = np.concatenate(pool)
        return torch.from_numpy(pool[rng.integers(len(pool), size=n)])

    step, updates, t_start, owed_disc = 0, 0, None, 0.0
    while step < total:
        for _ in range(train_every):
            if step < learning_starts:
                a = rng.uniform(-1, 1, act_dim).astype(np.float32)
            else:
                with torch.no_grad():
                    a = policy(torch.from_numpy(o)[None])[0][0].numpy()
            obs, _, term, trunc, info = env.step(torch.from_numpy(a)[None])
            o2, st = observe(obs, info)
            B_obs[step], B_act[step], B_next[step], B_stage[step], B_term[step] = o, a, o2, st, float(term)
            ep_next.append(o2)
            ep_stage.append(st)
            o = o2
            step += 1
            if bool(term) or bool(trunc):
                top = max(ep_stage)
                keep = len(ep_stage) if top == N else len(ep_stage) - ep_stage[::-1].index(top)
                stage_bufs[top].append(np.stack(ep_next[:keep]))
                ep_next, ep_stage = [], []
                obs, info = env.reset()
                o, _ = observe(obs, info)
        if step < learning_starts:
            continue
        if t_start is None:
            t_start, s0, u0 = time.perf_counter(), step - train_every, updates
        for _ in range(int(train_every * utd)):
            owed_disc += disc_updates  # fractional rates (0.5: every second update) carry over
            n_disc = int(owed_disc + 1e-9)
            owed_disc -= n_disc
            for k in [k for _ in range(n_disc) for k in range(N)]:  # discriminators
                neg, pos = sample_stages(0, k + 1, db), sample_stages(k + 1, N + 1, db)
                if neg is None or pos is None:
                    continue
                logit = disc[k](torch.cat([neg, pos]))
                label = torch.cat([torch.zeros(db, 1), torch.ones(db, 1)])
                loss_d = F.binary_cross_entropy_with_logits(logit, label)
                opt_d.zero_grad()
                loss_d.backward()
                opt_d.step()
            idx = rng.integers(step, size=batch_size)
            s, a, s2 = torch.from_numpy(B_obs[idx]), torch.from_numpy(B_act[idx]), torch.from_numpy(B_next[idx])
            r, d = reward(s2, torch.from_numpy(B_stage[idx])), torch.from_numpy(B_term[idx])
            alpha = log_alpha.exp().detach()
            with torch.no_grad():
                a2, logp2 = policy(s2)
                sa2 = torch.cat([s2, a2], -1)
                target = r + gamma * (1 - d) * (torch.min(q1_t(sa2), q2_t(sa2)) - alpha * logp2).squeeze(-1)
            sa = torch.cat([s, a], -1)
            loss_q = F.mse_loss(q1(sa).squeeze(-1), target) + F.mse_loss(q2(sa).squeeze(-1), target)
            opt_q.zero_grad()
            loss_q.backward()
            opt_q.step()
            pi, logp = policy(s)
            spi = torch.cat([s, pi], -1)
            loss_a = (alpha * logp - torch.min(q1(spi), q2(spi))).mean()
            opt_a.zero_grad()
            loss_a.backward()
            opt_a.step()
            loss_al = -(log_alpha * (logp.detach() - act_dim)).mean()
            opt_al.zero_grad()
            loss_al.backward()
            opt_al.step()
            with torch.no_grad():
                for net, tgt in ((q1, q1_t), (q2, q2_t)):
                    for p, pt in zip(net.parameters(), tgt.parameters()):
                        pt.mul_(1 - tau).add_(tau * p)
            updates += 1
    dt = time.perf_counter() - t_start
    env.close()
    return {
        "batch_size": batch_size,
        "utd": utd,
        "disc_updates": disc_updates,
        "disc_batch_size": db,
        "env_steps_per_s": (step - s0) / dt,
        "updates_per_s_overall": (updates - u0) / dt,
    }
