"""What the trained DQNs of the maze study learned: greedy behaviour and Q-values by distance to the goal.

    .venv/bin/python results/maze/diagnostics/q_values.py results/maze/run_files/{learn,reuse-drs,reuse-sparse,reuse-dense}-s0 \
        > results/maze/diagnostics/q_values.txt

For each run (``policy.pt`` + ``config.yaml``, on the run's own map):
- greedy episodes in 64 grids: success, and of the failed ones how many sit in one cell for their
  last 20 steps, with which action and in which cells;
- over every top-room goal and every free cell: the fraction of cells whose ``argmax_a Q(s, a)`` is
  a shortest-path move, and the mean of ``max_a Q`` and of the action gap (best minus second best)
  at shortest-path distance 1, 2, 5, 10, 20 and 30 from the goal.
"""

import collections
import sys

import torch
from omegaconf import OmegaConf
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from drs_torchrl.envs.maze import ACTIONS, MOVES, ThreeRoomMaze, decode_cells, observation
from drs_torchrl.tasks.maze import make_env
from drs_torchrl.updaters.dqn import q_network

torch.set_num_threads(1)
DISTANCES = (1, 2, 5, 10, 20, 30)


def greedy_behaviour(actor, cfg, map_name: str) -> str:
    env = make_env(map_name, 64, int(cfg.max_steps), 123, "sparse", coords=cfg.coords)
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        td = env.rollout(int(cfg.max_steps), actor, break_when_any_done=False)
    act = td["action"].float().argmax(-1)
    pos, _ = decode_cells(td["observation"], cfg.coords)
    done = td["next", "done"].squeeze(-1)
    first = done.float().argmax(-1)
    success = td["next", "success"].squeeze(-1)[torch.arange(64), first]
    fails = [i for i in range(64) if not success[i]]
    stuck = [i for i in fails if len({tuple(p.tolist()) for p in pos[i, -20:]}) == 1]
    stuck_act = collections.Counter(ACTIONS[int(act[i, -1])] for i in stuck)
    stuck_cells = collections.Counter(tuple(pos[i, -1].tolist()) for i in stuck)
    return (
        f"  greedy: success {float(success.float().mean()):.3f} (64 grids); {len(stuck)} of {len(fails)} failed "
        f"episodes sit in one cell for their last 20 steps, action there {dict(stuck_act)}; "
        f"most common cells {stuck_cells.most_common(4)}"
    )


def q_by_distance(actor, cfg, map_name: str) -> str:
    env = ThreeRoomMaze(map_name, num_envs=1)
    dist = env.shortest_distances()
    grid = env.grid
    free = (~grid).nonzero()
    n_opt = n_all = 0
    by_d = collections.defaultdict(list)
    for gi, goal in enumerate(env.goal_cells.tolist()):
        cells = free[(free != torch.tensor(goal)).any(-1)]
        obs = observation(grid, cells, torch.tensor(goal).expand(len(cells), 2), cfg.coords)
        with torch.no_grad():
            q = actor(TensorDict({"observation": obs}, [len(cells)]))["action_value"]
        best = q.argmax(-1)
        nxt = cells + MOVES[best]
        nxt = torch.where(grid[nxt[:, 0], nxt[:, 1]].unsqueeze(-1), cells, nxt)
        d = dist[gi]
        d_here = d[cells[:, 0], cells[:, 1]]
        n_opt += int((d[nxt[:, 0], nxt[:, 1]] == d_here - 1).sum())
        n_all += len(cells)
        top2 = q.topk(2, -1).values
        for k in DISTANCES:
            m = d_here == k
            if m.any():
                by_d[k].append(torch.stack([top2[m, 0], top2[m, 0] - top2[m, 1]], -1))
    lines = [
        f"  argmax_a Q(s, a) is a shortest-path move in {n_opt / n_all:.2f} of (cell, goal) pairs "
        f"(a uniform random action: about 0.34)"
    ]
    for k in DISTANCES:
        if by_d[k]:
            v = torch.cat(by_d[k])
            lines.append(
                f"  distance {k:2d}: mean max_a Q {float(v[:, 0].mean()):8.2f}, mean action gap {float(v[:, 1].mean()):.3f} ({len(v)} pairs)"
            )
    return "\n".join(lines)


def main(runs: list[str]) -> None:
    for run in runs:
        cfg = OmegaConf.load(f"{run}/config.yaml")
        map_name = cfg.map or ("train" if cfg.phase == "learn" else "test")
        env = make_env(map_name, 1, int(cfg.max_steps), 0, "sparse", coords=cfg.coords)
        actor = q_network(env, cfg.dqn.hidden)
        actor.load_state_dict(torch.load(f"{run}/policy.pt"))
        print(
            f"{run}: phase {cfg.phase}, map {map_name}, reward {cfg.reward.name}, coords {cfg.coords}, "
            f"gamma {cfg.dqn.gamma}, {cfg.total_frames} frames"
        )
        print(greedy_behaviour(actor, cfg, map_name))
        print(q_by_distance(actor, cfg, map_name))


if __name__ == "__main__":
    main(sys.argv[1:])
