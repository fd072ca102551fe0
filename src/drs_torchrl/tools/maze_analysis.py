"""What a learned maze reward says, and the maze study's report (``drs-maze phase=report``).

* :func:`reward_diagnostics`: the appendix's tabular property on a map: how often ``argmax_a R(s, a)``
  is a shortest-path move, and whether greedy ascent on ``R`` alone reaches the goal.
* :func:`plot_reward_map`: the paper's reward figure (five values per cell).
* :func:`report`: curves, CSV and table of a folder of runs.
"""

from __future__ import annotations

import csv
import functools
import json
import os
from pathlib import Path

import numpy as np
import torch
from omegaconf import ListConfig, OmegaConf

from drs_torchrl.envs.maze import (
    ACTIONS,
    GATES,
    MOVES,
    OBS_DIMS,
    SIZE,
    ThreeRoomMaze,
    free_cells,
    make_grid,
    observation,
)
from drs_torchrl.tasks.maze import MazeConfigError, reads_next_state, reward_coords  # noqa: F401 (re-exported)
from drs_torchrl.transforms import DrSReward


def all_state_actions(
    map_name: str, goal: tuple[int, int], coords: str = "onehot", next_state: bool = False
) -> tuple[torch.Tensor, torch.Tensor]:
    """Every free cell of a map (``(n, 2)``) and the features ``(n, 5, obs + 5)`` of each of its
    (state, action) pairs for a given goal cell; with ``next_state``, the observation ``(n, 5, obs)``
    of the cell each action leads to (walls block)."""
    grid = make_grid(map_name)
    cells = free_cells(grid)
    if next_state:
        tgt = cells.unsqueeze(1) + MOVES  # (n, 5, 2)
        nxt = torch.where(grid[tgt[..., 0], tgt[..., 1]].unsqueeze(-1), cells.unsqueeze(1).expand_as(tgt), tgt)
        return cells, observation(grid, nxt, torch.tensor(goal).expand(*nxt.shape[:-1], 2), coords)
    obs = observation(grid, cells, torch.tensor(goal).expand(len(cells), 2), coords)
    eye = torch.eye(len(ACTIONS))
    feats = torch.cat([obs.unsqueeze(1).expand(-1, len(ACTIONS), -1), eye.expand(len(cells), -1, -1)], -1)
    return cells, feats


def dense_reward_table(reward: DrSReward, map_name: str, goal: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    """``R(s, a)`` of every free cell and action at stage 0 (the learned term), ``(n, 5)``."""
    cells, feats = all_state_actions(map_name, goal, reward_coords(reward), reads_next_state(reward))
    net = (
        reward.discriminators if isinstance(reward, DrSReward) else reward.classifier
    )  # DrS, or a baseline's classifier
    with torch.no_grad():
        logits = net(feats)
        r = reward.combine(logits, torch.zeros(*logits.shape[:-1], 1, dtype=torch.long)).squeeze(-1)
    return cells, r


def reward_diagnostics(reward: DrSReward, map_name: str, max_steps: int) -> dict[str, float]:
    """How well the reward alone points the way on a map (the appendix's tabular property).

    ``optimal_action_rate``: fraction of (cell, goal) pairs, over every top-room goal and every free
    cell but the goal, where ``argmax_a R(s, a)`` is a shortest-path action (ties go to the first
    action, "up"). ``always_up_rate``: the same for a policy that always moves up, the reference
    for a reward without preferences (a constant reward scores exactly this). ``greedy_success``:
    fraction of (bottom-room start, goal) pairs from which following ``argmax_a R(s, a)`` reaches
    the goal within ``max_steps``.
    """
    env = ThreeRoomMaze(map_name, num_envs=1)
    dist = env.shortest_distances()  # (goals, 17, 17)
    grid = env.grid
    goals = env.goal_cells
    tables = torch.full((len(goals), SIZE, SIZE), 4, dtype=torch.long)  # best action per (goal, cell)
    n_opt = n_up = n_all = 0
    for gi, goal in enumerate(goals.tolist()):
        cells, r = dense_reward_table(reward, map_name, tuple(goal))
        d, not_goal = dist[gi], (cells != torch.tensor(goal)).any(-1)
        for a, counter in ((r.argmax(-1), "opt"), (torch.zeros(len(cells), dtype=torch.long), "up")):
            nxt = cells + MOVES[a]
            nxt = torch.where(grid[nxt[:, 0], nxt[:, 1]].unsqueeze(-1), cells, nxt)
            hits = int(((d[nxt[:, 0], nxt[:, 1]] == d[cells[:, 0], cells[:, 1]] - 1) & not_goal).sum())
            if counter == "opt":
                n_opt += hits
            else:
                n_up += hits
        n_all += int(not_goal.sum())
        tables[gi, cells[:, 0], cells[:, 1]] = r.argmax(-1)
    # greedy walks on argmax_a R from every bottom-room start, for every goal at once
    G, S = len(goals), len(env.start_cells)
    pos = env.start_cells.unsqueeze(0).expand(G, S, 2).clone()
    gidx = torch.arange(G).unsqueeze(-1).expand(G, S)
    done = torch.zeros(G, S, dtype=torch.bool)
    for _ in range(max_steps):
        tgt = pos + MOVES[tables[gidx, pos[..., 0], pos[..., 1]]]
        pos = torch.where(grid[tgt[..., 0], tgt[..., 1]].unsqueeze(-1), pos, tgt)
        done |= (pos == goals.unsqueeze(1)).all(-1)
    return {
        "optimal_action_rate": n_opt / max(n_all, 1),
        "always_up_rate": n_up / max(n_all, 1),
        "greedy_success": float(done.float().mean()),
    }


@functools.lru_cache(maxsize=None)
def always_up_rate(map_name: str) -> float:
    """:func:`reward_diagnostics`'s ``always_up_rate`` of a map (the reference a preference-free reward scores)."""
    flat = DrSReward(
        1, ["observation"], {"observation": OBS_DIMS["patch"]}, formula="rescaled", metadata={"reward_on": "next_state"}
    )  # untrained: the same value for every action
    return reward_diagnostics(flat, map_name, 1)["always_up_rate"]


def plot_reward_map(reward: DrSReward, path: str | os.PathLike, goal: tuple[int, int], maps=("train", "test")) -> Path:
    """The paper's reward figure: in each free cell, the learned reward of each of the five actions.

    Each cell is drawn as a 3x3 block: the up / down / left / right entries sit on the side the
    move goes to, *stay* in the middle. Lighter is higher. Walls are black and the goal has a red
    box. The values are ``R(s, a)`` at stage 0, i.e. ``alpha * tanh(D(s, a)) - 2``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    spot = {0: (0, 1), 1: (2, 1), 2: (1, 0), 3: (1, 2), 4: (1, 1)}  # action -> (row, col) in the block
    fig, axes = plt.subplots(1, len(maps), figsize=(7 * len(maps) + 1, 7.6), squeeze=False, layout="constrained")
    tables = [dense_reward_table(reward, m, goal) for m in maps]
    lo = min(float(r.min()) for _, r in tables)
    hi = max(float(r.max()) for _, r in tables)
    for ax, m, (cells, r) in zip(axes[0], maps, tables):
        img = np.full((SIZE * 3, SIZE * 3), np.nan)
        for (row, col), vals in zip(cells.tolist(), r.tolist()):
            for a, (dr, dc) in spot.items():
                img[row * 3 + dr, col * 3 + dc] = vals[a]
        walls = np.kron(make_grid(m).numpy().astype(float), np.ones((3, 3)))
        ax.set_facecolor("0.85")  # block corners (no action) and the background
        ax.imshow(np.where(walls > 0, 1.0, np.nan), cmap="gray_r", vmin=0, vmax=1, interpolation="nearest")
        im = ax.imshow(img, cmap="viridis", vmin=lo, vmax=hi if hi > lo else lo + 1e-6, interpolation="nearest")
        for k in range(SIZE + 1):  # cell borders
            ax.axhline(k * 3 - 0.5, color="white", linewidth=0.6)
            ax.axvline(k * 3 - 0.5, color="white", linewidth=0.6)
        ax.add_patch(Rectangle((goal[1] * 3 - 0.5, goal[0] * 3 - 0.5), 3, 3, fill=False, edgecolor="red", linewidth=2))
        ax.set_title(f"{m} map (gates at columns {GATES[m]})")
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(im, ax=axes[0].tolist(), shrink=0.9, label="R(s, a) at stage 0")
    fig.suptitle(
        "Learned reward R(s, a) per cell (lighter = higher): up / down / left / right on that side of the cell,\n"
        "stay in the middle; red box = goal"
    )
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def reward_label(summary: dict) -> str:
    """The reward's name in reports, with what the learned reward reads when that is not the agent's
    observation (``reward.coords``, e.g. ``drs[patch]``) and ``dqn.reward_scale`` when it is not 1."""
    name = summary["reward"]
    if name == "drs":
        tags = [summary["reward_coords"]] if summary.get("reward_coords") else []
        if summary.get("reward_input") == "next_state":
            tags.append("s'")
        name = f"drs[{', '.join(tags)}]" if tags else name
        if summary.get("phase") == "reuse" and summary.get("reward_alpha") == 0:
            name = f"{name} constant part (alpha=0)"
    scale = float(summary.get("reward_scale", 1.0))
    return name if scale == 1.0 else f"{name} x{scale:g}"


def report(root, out: str | os.PathLike) -> dict:
    """Gather ``summary.json`` / ``train.csv`` of every run under ``root`` (a folder, or a list of
    folders) into ``out``: ``curves.csv`` (every eval row of every run), ``curves.png`` (mean and
    std over seeds of the eval success rate against env steps) and ``table.md`` (final success
    rates per seed). Runs are grouped by phase and reward (with its scale, :func:`reward_label`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    roots = [Path(r) for r in (root if isinstance(root, (list, tuple, ListConfig)) else [root])]
    out = Path(out)
    runs = []
    for s in sorted(p for r in roots for p in r.rglob("summary.json")):
        summ = json.loads(s.read_text())
        if "reward_scale" not in summ and (s.parent / "config.yaml").exists():  # runs written before the fields existed
            c = OmegaConf.load(s.parent / "config.yaml")
            summ["reward_scale"] = float(c.dqn.get("reward_scale", 1.0))
            summ["reward_coords"] = c.reward.get("coords")
        with open(s.parent / "train.csv") as f:
            rows = list(csv.DictReader(f))
        runs.append((summ, rows, s.parent))
    if not runs:
        raise MazeConfigError(f"no runs (summary.json) under {', '.join(map(str, roots))}")
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "curves.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["phase", "map", "reward", "seed", "frames", "eval_success", "eval_length", "train_success"])
        for summ, rows, _ in runs:
            for r in rows:
                w.writerow(
                    [
                        summ["phase"],
                        summ["map"],
                        reward_label(summ),
                        summ["seed"],
                        r["frames"],
                        r["eval_success"],
                        r["eval_length"],
                        r["train_success"],
                    ]
                )
    groups: dict[tuple[str, str], list] = {}
    for summ, rows, d in runs:
        groups.setdefault((summ["phase"], summ["map"], reward_label(summ)), []).append((summ, rows, d))
    many_maps = {ph: len({m for p, m, _ in groups if p == ph}) > 1 for ph, _, _ in groups}
    agents = "/".join(sorted({str(s.get("algo", "dqn")).upper() for s, _, _ in runs}))  # runs before "algo": DQN
    panels = [
        ("learn", "phase 1: DrS reward learning (train map)"),
        ("reuse", f"phase 2: fresh {agents} on the test map"),
    ]
    panels = [p for p in panels if any(ph == p[0] for ph, _, _ in groups)]  # no empty panel
    fig, axes = plt.subplots(1, len(panels), figsize=(6 * len(panels), 4.2), squeeze=False)
    axes = axes[0]
    table = [
        "| phase | map | reward | seeds | env steps | eval success at the end (per seed) | mean +- std | mean over the last 3 evals | wall time per run (s) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for ax, (phase, title) in zip(axes, panels):
        for (ph, map_name, rname), members in sorted(groups.items()):
            if ph != phase:
                continue
            legend = f"{rname} on {map_name}" if many_maps[ph] else rname
            frames = np.array([float(r["frames"]) for r in members[0][1]])
            n = min(len(m[1]) for m in members)
            curves = np.array([[float(r["eval_success"]) for r in m[1][:n]] for m in members])
            mean, std = curves.mean(0), curves.std(0)
            ax.plot(frames[:n], mean, label=f"{legend} ({len(members)} seeds)")
            ax.fill_between(frames[:n], mean - std, mean + std, alpha=0.25)
            finals = [m[0]["final_eval_success"] for m in members]
            last3 = [m[0]["mean_eval_success_last3"] for m in members]
            table.append(
                f"| {phase} | {members[0][0]['map']} | {rname} | {', '.join(str(m[0]['seed']) for m in members)} | "
                f"{members[0][0]['frames']} | {', '.join(f'{x:.2f}' for x in finals)} | {np.mean(finals):.2f} +- {np.std(finals):.2f} | "
                f"{np.mean(last3):.2f} | {np.mean([m[0]['wall_time_s'] for m in members]):.0f} |"
            )
        ax.set_title(title if not many_maps.get(phase) else title.split(" on the ")[0] + " (map in the legend)")
        ax.set_xlabel("env steps")
        ax.set_ylabel("greedy eval success rate")
        ax.set_ylim(-0.05, 1.05)
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:  # a phase without runs gets no empty legend
            ax.legend(loc="upper left")
    fig.tight_layout()
    fig.savefig(out / "curves.png", dpi=110)
    plt.close(fig)
    diag = [
        "",
        "| learned reward (seed) | map | argmax_a R(s,a) is a shortest-path action | same for always moving up (reference) | greedy on R reaches the goal |",
        "|---|---|---|---|---|",
    ]
    for summ, _, _ in runs:
        if summ["phase"] == "learn" and "reward_diagnostics" in summ:
            for m, v in summ["reward_diagnostics"].items():
                up = f"{v.get('always_up_rate', always_up_rate(m)):.2f}"  # runs written before the field existed: computed
                diag.append(
                    f"| {reward_label(summ)} {summ['seed']} | {m} | {v['optimal_action_rate']:.2f} | {up} | {v['greedy_success']:.2f} |"
                )
    (out / "table.md").write_text("\n".join(table + diag) + "\n")
    return {"runs": len(runs), "out": str(out)}
