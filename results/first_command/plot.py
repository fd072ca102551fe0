"""spread.png: the first command's test-map curves on seeds 0-9 (greedy success of the reused DrS reward, sparse and
semi-sparse), from the committed records; seeds 5-9 (pre-registered) drawn solid, seeds 0-4 dashed.

usage: python results/first_command/plot.py   (from the repository root)
"""

import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

ROOT = Path("results")
PLACES = [ROOT / "quickstart", ROOT / "first_command" / "selection", ROOT / "first_command" / "test"]
REWARDS = [("drs", "DrS (frozen, reused)"), ("sparse", "sparse"), ("semi_sparse", "semi-sparse")]


def run_dir(seed: int, reward: str) -> Path | None:
    for place in PLACES:
        d = place / f"seed{seed}" / f"reuse-{reward}"
        if (d / "train.csv").is_file():
            return d
    return None


def main() -> None:
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6), sharey=True)
    for ax, (reward, label) in zip(axes, REWARDS):
        solved = total = 0
        for seed in range(10):
            d = run_dir(seed, reward)
            if d is None:
                continue
            rows = list(csv.DictReader(open(d / "train.csv")))
            frames = [float(r["frames"]) / 1000 for r in rows]
            success = [float(r["eval_success"]) for r in rows]
            last3 = sum(success[-3:]) / 3
            total, solved = total + 1, solved + (last3 >= 0.9)
            ax.plot(frames, success, "-" if seed >= 5 else "--", color=f"C{seed}", lw=1.2, label=f"seed {seed}")
        ax.set_title(f"{label}: >= 0.9 in {solved} of {total} seeds", fontsize=10)
        ax.set_xlabel("env steps (k)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("greedy success, test map")
    axes[0].legend(fontsize=7, ncol=2, loc="upper left")
    fig.suptitle("drs-quickstart on ten seeds (solid: seeds 5-9, pre-registered; dashed: seeds 0-4)", fontsize=11)
    fig.tight_layout()
    fig.savefig(ROOT / "first_command" / "spread.png", dpi=110)


if __name__ == "__main__":
    main()
