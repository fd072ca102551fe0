"""``drs-probe``: does a learned DrS reward point toward the next stage on new variants? A probe along a policy's episodes.

Rolls out a trained policy (sampled actions, so the states vary) on each split, and at every next state
records the stage, each discriminator's ``tanh(D_k(s'))`` and ManiSkill's normalized dense reward (the
human-engineered progress measure). Within each stage k it reports how well ``tanh(D_k)`` ranks states
the way the dense reward does (Spearman rank correlation): a reward whose within-stage term ranks
states as the dense reward does gives the agent a direction toward stage k+1 (Sec. 4.2); one near 0
leaves the agent in stage k with the semi-sparse staircase alone.

    drs-probe --reward LEARN_RUN/checkpoints/reward.pt --policy RUN_DIR --splits train test --episodes 20 --out probe/
    drs-probe --reward R.pt --policy HOLDING_AGENT --swap-with PLACING_AGENT --splits test --out probe/

``--reward`` is a DrS ``reward.pt`` (a run's ``checkpoints/reward.pt`` or a committed record's ``reward.pt``);
``--policy`` a drs-learn / drs-reuse run directory or committed record (its ``config.yaml`` and ``policy.pt``).

Writes ``probe.json``, ``probe.md`` and ``probe.png`` (tanh(D_k) against the dense reward, per stage and split).

``--swap-with RUN_DIR`` also asks which inputs drive ``D_k``: it rolls out a second policy on the first split,
and for each group of input columns (the family's observation layout where it names one, e.g. joint
velocities; else one group per input key) puts the second policy's values into the first's stage-k states
(and the other way round), and reports the mean ``tanh(D_k)`` after each swap (``feature_swap.md/json``).
A group whose swap moves the score from one policy's level to the other's is what ``D_k`` reads.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from drs_torchrl.runtime.console import at_least, console_script
import torch


def spearman(x: np.ndarray, y: np.ndarray) -> float:
    """Rank correlation (average ranks for ties); NaN with fewer than 3 points or a constant input."""
    if len(x) < 3 or np.ptp(x) == 0 or np.ptp(y) == 0:
        return float("nan")
    from scipy.stats import spearmanr

    return float(spearmanr(x, y).statistic)


def rollout(
    policy_dir, reward, split: str, episodes: int, seed: int, deterministic: bool, variant_overrides: dict | None = None
) -> dict:
    """Per next state of ``episodes`` episodes: stage, tanh(D_k) for every k, dense reward; and the success rate.
    ``variant_overrides`` update the policy run's (e.g. ``placed_thresh``: label the stages as the reward's run did)."""
    from omegaconf import OmegaConf
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from drs_torchrl.envs.factory import make_family_env
    from drs_torchrl.models import load_policy
    from drs_torchrl.runtime.rundir import load_run_config
    from drs_torchrl.tasks import TASK_OBSERVATION_KEY, family_from_config, with_task_observation

    cfg = load_run_config(policy_dir, needs=("env",))
    # a reward that reads the task state gets it from the env, whatever the policy's run had
    family = with_task_observation(family_from_config(cfg.env), TASK_OBSERVATION_KEY in reward.reward_in_keys)
    overrides = {**(OmegaConf.to_container(cfg.env.variant_overrides) or {}), **(variant_overrides or {})} or None
    env = make_family_env(
        family,
        split,
        seed=seed,
        variant_overrides=overrides,
        reward_mode="normalized_dense",
        control_mode=cfg.env.control_mode,
        max_episode_steps=cfg.env.max_episode_steps,
    )
    actor, _ = load_policy(policy_dir, env.observation_spec, env.action_spec, family=family.name)
    mode = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
    cols = {"stage": [], "tanh_d": [], "dense": [], "success": [], "features": []}
    try:
        for _ in range(episodes):
            with set_exploration_type(mode), torch.no_grad():
                ep = env.rollout(100_000, actor, break_when_any_done=True, auto_reset=True)
            nxt = ep.get("next")
            with torch.no_grad():
                feats = reward.features(nxt).reshape(len(nxt), -1)
                logits = reward.discriminators(feats)
            cols["features"].append(feats)
            cols["stage"].append(nxt.get("stage").reshape(-1).numpy())
            cols["tanh_d"].append(torch.tanh(logits).reshape(len(nxt), -1).numpy())
            cols["dense"].append(nxt.get("reward").reshape(-1).numpy())
            cols["success"].append(bool(nxt.get("success").any()))
    finally:
        env.close()
    return {
        "stage": np.concatenate(cols["stage"]),
        "tanh_d": np.concatenate(cols["tanh_d"]),
        "features": torch.cat(cols["features"]),
        "family": family,
        "dense": np.concatenate(cols["dense"]),
        "success_rate": float(np.mean(cols["success"])),
        "num_stages": reward.num_stages,
    }


def feature_groups(family, reward) -> dict[str, tuple[int, int]]:
    """Named column ranges of the reward's input vector: the family's layout of an input key where it names
    one (``extra["<key>_groups"]``, e.g. ``observation_groups``), else one group per input key."""
    groups, start = {}, 0
    for key, size in reward.in_shapes.items():
        layout = family.extra.get(f"{key}_groups") if isinstance(key, str) else None
        if layout and max(e for _, e in layout.values()) == size:
            groups.update({name: (start + a, start + b) for name, (a, b) in layout.items()})
        else:
            groups[str(key)] = (start, start + size)
        start += size
    return groups


def feature_swap(
    score, fa: torch.Tensor, fb: torch.Tensor, groups: dict[str, tuple[int, int]], seed: int = 0
) -> list[dict]:
    """For each column group: mean ``score`` of ``fa`` with that group taken from random rows of ``fb``, and
    of ``fb`` with it taken from ``fa``. ``score`` maps ``(n, d)`` features to ``(n,)`` values."""
    g = torch.Generator().manual_seed(seed)
    ia = torch.randint(len(fa), (len(fb),), generator=g)  # rows of fa that lend to fb
    ib = torch.randint(len(fb), (len(fa),), generator=g)
    rows = [{"group": "(none)", "a": float(score(fa).mean()), "b": float(score(fb).mean())}]
    for name, (s, e) in groups.items():
        x, y = fa.clone(), fb.clone()
        x[:, s:e] = fb[ib, s:e]
        y[:, s:e] = fa[ia, s:e]
        rows.append(
            {
                "group": name,
                "columns": [s, e],
                "a": float(score(x).mean()),
                "b": float(score(y).mean()),
                # how the two sides differ there: the mean Euclidean norm of the group's values
                "norm_a": float(fa[:, s:e].norm(dim=-1).mean()),
                "norm_b": float(fb[:, s:e].norm(dim=-1).mean()),
            }
        )
    return rows


def summarize(data: dict) -> list[dict]:
    rows = []
    for k in range(data["num_stages"]):  # the last stage (success) ends the episode and has no discriminator
        m = data["stage"] == k
        t, d = data["tanh_d"][m, k], data["dense"][m]
        rows.append(
            {
                "stage": k,
                "states": int(m.sum()),
                "tanh_d_mean": float(t.mean()) if m.any() else float("nan"),
                "tanh_d_min": float(t.min()) if m.any() else float("nan"),
                "tanh_d_max": float(t.max()) if m.any() else float("nan"),
                "spearman_vs_dense": spearman(t, d),
            }
        )
    return rows


@console_script("drs-probe")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="drs-probe",
        description=__doc__.split("\n\n", 1)[0].replace("``", ""),
        epilog=__doc__.split("\n\n", 1)[1].replace("``", ""),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--reward", required=True, help="a DrS reward.pt")
    p.add_argument("--policy", required=True, help="a drs-learn / drs-reuse run directory (or record) with policy.pt")
    p.add_argument(
        "--splits",
        nargs="+",
        default=["train", "test"],
        help="splits or variant names to roll out on (default: train test)",
    )
    p.add_argument("--episodes", type=at_least(1), default=20, help="episodes per split (default 20)")
    p.add_argument("--deterministic", action="store_true", help="the mean action (default: sampled actions)")
    p.add_argument("--seed", type=int, default=0, help="seeds the env and the sampled actions (default 0)")
    p.add_argument(
        "--swap-with",
        default=None,
        metavar="RUN_DIR",
        help="a second policy: swap input groups between its stage-k states and --policy's (first split)",
    )
    p.add_argument(
        "--variant-override",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="an env variant parameter over the policy run's (repeatable), e.g. placed_thresh=0.05 to label "
        "the stages as a reward learned with that threshold does",
    )
    p.add_argument("--out", type=Path, required=True, help="folder for probe.json/md/png (and feature_swap.json/md)")
    a = p.parse_args(argv)
    try:  # values typed as YAML reads them, as Hydra overrides are
        import yaml

        a.overrides = {k: yaml.safe_load(v) for k, v in (o.split("=", 1) for o in a.variant_override)}
    except ValueError:
        p.error(f"--variant-override takes KEY=VALUE, got {a.variant_override}")
    from drs_torchrl.runtime.console import quiet_libraries
    from drs_torchrl.transforms.reward import DrSReward, load_reward

    quiet_libraries()
    torch.set_num_threads(1)
    torch.manual_seed(a.seed)  # the sampled actions; the env's initial states are seeded by make_family_env
    reward = load_reward(a.reward)
    if not isinstance(reward, DrSReward):
        p.error(f"{a.reward} is not a DrS reward")
    a.out.mkdir(parents=True, exist_ok=True)
    report, data = (
        {
            "reward": a.reward,
            "policy": a.policy,
            "episodes": a.episodes,
            "variant_overrides": a.overrides,
            "actions": "deterministic" if a.deterministic else "sampled",
            "splits": {},
        },
        {},
    )
    for split in a.splits:
        data[split] = rollout(a.policy, reward, split, a.episodes, a.seed, a.deterministic, a.overrides)
        report["splits"][split] = {"success_rate": data[split]["success_rate"], "stages": summarize(data[split])}
        print(f"{split}: success {data[split]['success_rate']:.2f}", file=sys.stderr)
    (a.out / "probe.json").write_text(json.dumps(report, indent=1))
    if a.swap_with:
        write_feature_swap(a, reward, data[a.splits[0]])
    lines = [
        f"Reward `{a.reward}` along {a.episodes} episodes ({report['actions']} actions) of the policy `{a.policy}`"
        + (f", env variant overrides {a.overrides} (stages labelled with them)." if a.overrides else "."),
        "Spearman: rank correlation of tanh(D_k(s')) with ManiSkill's normalized dense reward over the stage-k states.",
        "",
        "| split | policy success | stage k | states | tanh(D_k) mean [min, max] | Spearman vs dense |",
        "|---|---|---|---|---|---|",
    ]
    for split, r in report["splits"].items():
        for s in r["stages"]:
            lines.append(
                f"| {split} | {r['success_rate']:.2f} | {s['stage']} | {s['states']} | {s['tanh_d_mean']:.2f} "
                f"[{s['tanh_d_min']:.2f}, {s['tanh_d_max']:.2f}] | {s['spearman_vs_dense']:.2f} |"
            )
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


def write_feature_swap(a, reward, first: dict) -> None:
    split = a.splits[0]
    other = rollout(a.swap_with, reward, split, a.episodes, a.seed, a.deterministic, a.overrides)
    groups = feature_groups(first["family"], reward)
    out = {"reward": a.reward, "a": a.policy, "b": a.swap_with, "split": split, "episodes": a.episodes, "stages": []}
    lines = [
        f"Which inputs drive `tanh(D_k)` of `{a.reward}`: stage-k states of A = `{a.policy}` and B = `{a.swap_with}`",
        f"({a.episodes} episodes each, {split} split, {'deterministic' if a.deterministic else 'sampled'} actions). Each row puts",
        "one group of B's input columns into A's states (random pairing) and A's into B's; mean tanh(D_k) after the swap.",
        "",
    ]
    for k in range(reward.num_stages):
        ma, mb = first["stage"] == k, other["stage"] == k
        if ma.sum() < 3 or mb.sum() < 3:
            continue
        fa, fb = first["features"][torch.as_tensor(ma)], other["features"][torch.as_tensor(mb)]

        def score(f, k=k):
            with torch.no_grad():
                return torch.tanh(reward.discriminators(f))[..., k].reshape(-1)

        rows = feature_swap(score, fa, fb, groups, a.seed)
        out["stages"].append({"stage": k, "states_a": int(ma.sum()), "states_b": int(mb.sum()), "rows": rows})
        lines += [
            f"**stage {k}** ({int(ma.sum())} states of A, {int(mb.sum())} of B)",
            "",
            "| input group swapped | A's states, mean tanh(D_k) | B's states, mean tanh(D_k) | mean norm of the group, A / B |",
            "|---|---|---|---|",
        ]
        lines += [
            f"| {r['group']} | {r['a']:.2f} | {r['b']:.2f} | "
            + (f"{r['norm_a']:.3g} / {r['norm_b']:.3g} |" if "norm_a" in r else "- |")
            for r in rows
        ] + [""]
    (a.out / "feature_swap.json").write_text(json.dumps(out, indent=1))
    (a.out / "feature_swap.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    sys.exit(main())
