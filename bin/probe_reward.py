#!/usr/bin/env python
"""Does a learned DrS reward point toward the next stage on new variants? A probe along a policy's episodes.

Rolls out a trained policy (sampled actions, so the states vary) on each split, and at every next state
records the stage, each discriminator's ``tanh(D_k(s'))`` and ManiSkill's normalized dense reward (the
human-engineered progress measure). Within each stage k it reports how well ``tanh(D_k)`` ranks states
the way the dense reward does (Spearman rank correlation): a reward whose within-stage term ranks
states as the dense reward does gives the agent a direction toward stage k+1 (Sec. 4.2); one near 0
leaves the agent in stage k with the semi-sparse staircase alone.

    .venv/bin/python bin/probe_reward.py --reward R/reward.pt --policy RUN_DIR --splits train test --episodes 20 \\
        --out results/reuse/pick_cube/probe

Writes ``probe.json``, ``probe.md`` and ``probe.png`` (tanh(D_k) against the dense reward, per stage and split).
"""
import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch


def spearman(x: np.ndarray, y: np.ndarray) -> float:
    """Rank correlation (average ranks for ties); NaN with fewer than 3 points or a constant input."""
    if len(x) < 3 or np.ptp(x) == 0 or np.ptp(y) == 0:
        return float("nan")
    from scipy.stats import spearmanr

    return float(spearmanr(x, y).statistic)


def rollout(policy_dir, reward, split: str, episodes: int, seed: int, deterministic: bool) -> dict:
    """Per next state of ``episodes`` episodes: stage, tanh(D_k) for every k, dense reward; and the success rate."""
    from omegaconf import OmegaConf
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from drs_torchrl.envs.factory import make_family_env
    from drs_torchrl.models import load_policy
    from drs_torchrl.tasks import family_from_config

    cfg = OmegaConf.load(Path(policy_dir) / "config.yaml")
    family = family_from_config(cfg.env)
    overrides = OmegaConf.to_container(cfg.env.variant_overrides) or None
    env = make_family_env(family, split, seed=seed, variant_overrides=overrides, reward_mode="normalized_dense",
                          control_mode=cfg.env.control_mode, max_episode_steps=cfg.env.max_episode_steps)
    actor, _ = load_policy(policy_dir, env.observation_spec, env.action_spec, family=family.name)
    mode = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
    cols = {"stage": [], "tanh_d": [], "dense": [], "success": []}
    try:
        for _ in range(episodes):
            with set_exploration_type(mode), torch.no_grad():
                ep = env.rollout(100_000, actor, break_when_any_done=True, auto_reset=True)
            nxt = ep.get("next")
            with torch.no_grad():
                logits = reward.discriminators(reward.features(nxt))
            cols["stage"].append(nxt.get("stage").reshape(-1).numpy())
            cols["tanh_d"].append(torch.tanh(logits).reshape(len(nxt), -1).numpy())
            cols["dense"].append(nxt.get("reward").reshape(-1).numpy())
            cols["success"].append(bool(nxt.get("success").any()))
    finally:
        env.close()
    return {"stage": np.concatenate(cols["stage"]), "tanh_d": np.concatenate(cols["tanh_d"]),
            "dense": np.concatenate(cols["dense"]), "success_rate": float(np.mean(cols["success"])), "num_stages": reward.num_stages}


def summarize(data: dict) -> list[dict]:
    rows = []
    for k in range(data["num_stages"]):  # the last stage (success) ends the episode and has no discriminator
        m = data["stage"] == k
        t, d = data["tanh_d"][m, k], data["dense"][m]
        rows.append({"stage": k, "states": int(m.sum()),
                     "tanh_d_mean": float(t.mean()) if m.any() else float("nan"),
                     "tanh_d_min": float(t.min()) if m.any() else float("nan"),
                     "tanh_d_max": float(t.max()) if m.any() else float("nan"),
                     "spearman_vs_dense": spearman(t, d)})
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--reward", required=True, help="a DrS reward.pt")
    p.add_argument("--policy", required=True, help="a drs-learn / drs-reuse run directory (or record) with policy.pt")
    p.add_argument("--splits", nargs="+", default=["train", "test"])
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--deterministic", action="store_true", help="the mean action (default: sampled actions)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, required=True)
    a = p.parse_args(argv)
    from drs_torchrl.console import quiet_libraries
    from drs_torchrl.transforms.reward import DrSReward, load_reward

    quiet_libraries()
    torch.set_num_threads(1)
    torch.manual_seed(a.seed)  # the sampled actions; the env's initial states are seeded by make_family_env
    reward = load_reward(a.reward)
    if not isinstance(reward, DrSReward):
        p.error(f"{a.reward} is not a DrS reward")
    a.out.mkdir(parents=True, exist_ok=True)
    report, data = {"reward": a.reward, "policy": a.policy, "episodes": a.episodes,
                    "actions": "deterministic" if a.deterministic else "sampled", "splits": {}}, {}
    for split in a.splits:
        data[split] = rollout(a.policy, reward, split, a.episodes, a.seed, a.deterministic)
        report["splits"][split] = {"success_rate": data[split]["success_rate"], "stages": summarize(data[split])}
        print(f"{split}: success {data[split]['success_rate']:.2f}", file=sys.stderr)
    (a.out / "probe.json").write_text(json.dumps(report, indent=1))
    lines = [f"Reward `{a.reward}` along {a.episodes} episodes ({report['actions']} actions) of the policy `{a.policy}`.",
             "Spearman: rank correlation of tanh(D_k(s')) with ManiSkill's normalized dense reward over the stage-k states.", "",
             "| split | policy success | stage k | states | tanh(D_k) mean [min, max] | Spearman vs dense |", "|---|---|---|---|---|---|"]
    for split, r in report["splits"].items():
        for s in r["stages"]:
            lines.append(f"| {split} | {r['success_rate']:.2f} | {s['stage']} | {s['states']} | {s['tanh_d_mean']:.2f} "
                         f"[{s['tanh_d_min']:.2f}, {s['tanh_d_max']:.2f}] | {s['spearman_vs_dense']:.2f} |")
    (a.out / "probe.md").write_text("\n".join(lines) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = reward.num_stages
    fig, axes = plt.subplots(1, n, figsize=(4.2 * n, 3.6), squeeze=False)
    for k, ax in enumerate(axes[0]):
        for j, (split, d) in enumerate(data.items()):
            m = d["stage"] == k
            ax.scatter(d["dense"][m], d["tanh_d"][m, k], s=6, alpha=0.5, color=f"C{j}", label=split)
        ax.set_title(f"stage {k} states: tanh(D_{k})", fontsize=10)
        ax.set_xlabel("ManiSkill normalized dense reward")
        ax.set_ylim(-1.05, 1.05)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(a.out / "probe.png", dpi=110)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
