"""``drs-plot RUN_DIR [RUN_DIR ...]``: figures of a run from its ``train.csv`` / ``eval.csv``.

One PNG per run (``<run_dir>/progress.png``, or ``--out``): per-stage reach rates and success of
training episodes, evaluation success, discriminator accuracy per stage, reward statistics and
env steps/s, all against env steps. Several runs given together are overlaid in one figure.
``drs-plot RUN_DIR --reward-episode``: the paper's Fig. 3, the learned reward along one episode
against the semi-sparse staircase it fills in (``reward_episode.png``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from drs_torchrl.runtime.console import at_least, console_script
from drs_torchrl.runtime.rundir import maze_run_message, read_run_csv


def load(run_dir: Path):
    if maze := maze_run_message(run_dir):
        raise ValueError(maze)
    train = read_run_csv(run_dir / "train.csv") if (run_dir / "train.csv").exists() else None
    ev = read_run_csv(run_dir / "eval.csv") if (run_dir / "eval.csv").exists() else None
    if train is None:
        raise FileNotFoundError(f"{run_dir} has no train.csv: is it a drs-learn/drs-reuse run directory?")
    return train, ev


def plot_runs(run_dirs: list[Path], out: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(16, 8.5))
    ax_reach, ax_eval, ax_disc, ax_rew, ax_speed, ax_buf = axes.ravel()
    for run in run_dirs:
        train, ev = load(run)
        tag = run.name if len(run_dirs) > 1 else ""
        x = train["step"]
        for c in sorted(c for c in train.columns if c.startswith("reach_stage_")):
            ax_reach.plot(x, train[c], label=f"{tag} {c.replace('reach_', '')}".strip())
        if ev is not None:
            ax_eval.plot(ev["step"], ev["success_rate"], marker="o", label=f"{tag} eval success".strip())
            for c in sorted(c for c in ev.columns if c.startswith("reach_stage_")):
                ax_eval.plot(
                    ev["step"], ev[c], ls="--", alpha=0.6, label=f"{tag} eval {c.replace('reach_', '')}".strip()
                )
        for c in sorted(c for c in train.columns if c.startswith("disc_accuracy_")):
            ax_disc.plot(x, train[c], label=f"{tag} D_{c.rsplit('_', 1)[1]}".strip())
        if "disc_accuracy" in train and train["disc_accuracy"].notna().any():  # a baseline's single classifier
            ax_disc.plot(x, train["disc_accuracy"], label=f"{tag} classifier".strip())
        if "reward_mean" in train:
            ax_rew.plot(x, train["reward_mean"], label=f"{tag} mean".strip())
            ax_rew.fill_between(x, train["reward_min"], train["reward_max"], alpha=0.15)
        ax_speed.plot(x, train["env_steps_per_s"], label=f"{tag} env steps/s".strip())
        if "updates_per_s" in train:
            ax_speed.plot(x, train["updates_per_s"], ls="--", label=f"{tag} updates/s".strip())
        for c in sorted(c for c in train.columns if c.startswith("stage_buffer_")):
            ax_buf.plot(x, train[c], label=f"{tag} B_{c.rsplit('_', 1)[1]}".strip())
    titles = [
        ("training episodes reaching stage k (rolling)", "rate", (0, 1.02)),
        ("evaluation (deterministic policy)", "rate", (0, 1.02)),
        ("discriminator accuracy per stage (or the classifier's)", "accuracy", (0.4, 1.02)),
        ("reward on SAC batches (mean, min-max)", "reward", None),
        ("throughput", "per second", None),
        ("stage buffers (transitions)", "transitions", None),
    ]
    for ax, (t, yl, ylim) in zip(axes.ravel(), titles):
        ax.set_title(t, fontsize=10)
        ax.set_xlabel("env steps")
        ax.set_ylabel(yl)
        if ylim:
            ax.set_ylim(*ylim)
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    if ax_buf.get_lines():
        ax_buf.set_yscale("symlog")
    fig.suptitle(", ".join(str(r) for r in run_dirs), fontsize=9)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def plot_reward_episode(run_dir: Path, out: Path, *, split: str | None = None, tries: int = 10, seed: int = 0) -> Path:
    """The paper's Fig. 3 for one episode: the learned reward step by step against the semi-sparse
    staircase (the stage index in the reward's own units) that it fills in.

    Of ``tries`` sampled-action episodes of the run's policy, the one reaching the highest stage is drawn.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from drs_torchrl.apps.evaluate import EvalError, evaluate_run

    res = evaluate_run(run_dir, episodes=tries, split=split, deterministic=False, seed=seed, keep_episodes=True)
    desc = res["reward"]
    if "num_stages" not in desc:
        raise EvalError(
            f"{run_dir} trained with reward={desc['name']}, not a learned DrS reward: nothing to illustrate"
        )
    best = max(range(len(res["rows"])), key=lambda i: (res["rows"][i]["stage"], -i))
    ep = res["episodes_data"][best]
    N, formula, offset = desc["num_stages"], desc["formula"], desc["offset"]
    stage = np.asarray(ep["stage"], dtype=float)
    staircase = stage / N + offset if formula == "rescaled" else stage
    t = np.arange(1, len(stage) + 1)
    fig, ax = plt.subplots(figsize=(7, 3.6))
    ax.step(t, staircase, where="post", color="0.45", lw=2, label="semi-sparse (stage index)")
    ax.plot(t, ep["reward"], color="C0", lw=1.8, marker=".", ms=4, label="learned DrS reward")
    for k in range(1, N + 1):
        hits = np.nonzero(stage >= k)[0]
        if hits.size:
            ax.axvline(t[hits[0]], color=f"C{k}", ls=":", lw=1)
            ax.text(t[hits[0]], ax.get_ylim()[1], f" stage {k}", color=f"C{k}", va="top", fontsize=8)
    ax.set_xlabel("step of the episode")
    ax.set_ylabel("reward")
    ax.set_title(f"{res['family']} ({res['split']}): one episode reaching stage {int(stage.max())} of {N}", fontsize=10)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


@console_script("drs-plot")
def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="drs-plot", description="plot drs-torchrl runs")
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--out", type=Path, default=None)
    p.add_argument(
        "--reward-episode",
        action="store_true",
        help="instead: the learned reward along one episode of the run's policy against the semi-sparse "
        "staircase (the paper's Fig. 3), written to RUN/reward_episode.png",
    )
    p.add_argument("--split", default=None, help="with --reward-episode: train | test | a variant (default: the run's)")
    p.add_argument(
        "--tries",
        type=at_least(1),
        default=10,
        help="with --reward-episode: episodes tried; the furthest-reaching is drawn",
    )
    a = p.parse_args(argv)
    if a.reward_episode and len(a.runs) > 1:
        p.error(f"--reward-episode draws one run's episode; give one run directory, not {len(a.runs)}")
    try:
        if a.reward_episode:
            from drs_torchrl.runtime.console import quiet_libraries

            quiet_libraries()
            out = plot_reward_episode(
                a.runs[0], a.out or a.runs[0] / "reward_episode.png", split=a.split, tries=a.tries
            )
        else:
            out = plot_runs(a.runs, a.out or a.runs[0] / "progress.png")
    except (FileNotFoundError, ValueError, KeyError) as exc:
        print(f"drs-plot: error: {exc}", file=sys.stderr)
        return 2
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
