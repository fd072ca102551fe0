"""The paper's tabular claim (Appendix, "Analysis on a Simple Tabular Case").

On a deterministic grid with one stage (success = reaching the goal), once the policy has converged
to a shortest-path policy, the greedy policy ``argmax_a R(s, a)`` of the learned reward reaches the
goal by a shortest path from every start. Algorithm 1 runs here in tabular form with the project's
own pieces: ``StageBuffers`` (one stage: success / failure rings, finite), ``DiscriminatorLoss`` and
``DrSReward`` reading a one-hot of (s, a); a Q-learning agent trains on the learned reward, with
exploration annealed to zero (the analysis assumes the policy converges).
"""

from collections import deque

import pytest
import numpy as np
import torch
from tensordict import TensorDict

from drs_torchrl.data import StageBuffers
from drs_torchrl.objectives import DiscriminatorLoss
from drs_torchrl.transforms import DrSReward

GRID = [
    ".....",
    ".###.",
    "...#.",
    ".#...",
    "...#G",
]
MOVES = [(-1, 0), (1, 0), (0, -1), (0, 1)]  # up, down, left, right
H, W, A = len(GRID), len(GRID[0]), len(MOVES)
CELLS = [(r, c) for r in range(H) for c in range(W) if GRID[r][c] != "#"]
GOAL = next((r, c) for r, c in CELLS if GRID[r][c] == "G")
INDEX = {cell: i for i, cell in enumerate(CELLS)}
S = len(CELLS)


def step(cell, a):
    r, c = cell[0] + MOVES[a][0], cell[1] + MOVES[a][1]
    if 0 <= r < H and 0 <= c < W and GRID[r][c] != "#":
        return (r, c)
    return cell  # bump: stay


def shortest_distances():
    dist = {GOAL: 0}
    q = deque([GOAL])
    while q:
        cell = q.popleft()
        for a in range(A):  # moves are reversible on a grid
            prev = step(cell, a)
            if prev not in dist:
                dist[prev] = dist[cell] + 1
                q.append(prev)
    return dist


def sa_onehot(s, a):
    x = torch.zeros(S * A)
    x[INDEX[s] * A + a] = 1.0
    return x


@pytest.mark.slow
def test_greedy_on_the_learned_reward_follows_shortest_paths():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # tiny tensors: one thread is faster and deterministic
    try:
        _run_tabular_drs()
    finally:
        torch.set_num_threads(threads)


def _run_tabular_drs():
    rng = np.random.default_rng(0)
    torch.manual_seed(0)
    # finite stage rings (the analysis' "large enough, but not infinite" buffers): the failure ring
    # keeps the failures of the exploration phase, which try every action everywhere; the success
    # ring is small enough that the converged agent's successes replace the exploratory ones
    capacity = 1200
    reward = DrSReward(1, ["sa"], {"sa": S * A}, formula="rescaled")
    buffers = StageBuffers(1, ["sa"], capacity=capacity, batch_size=64)
    loss = DiscriminatorLoss(reward.discriminators, ["sa"], early_stop_threshold=None)
    opt = torch.optim.Adam(reward.discriminators.parameters(), lr=1e-2)
    all_sa = torch.eye(S * A)  # row INDEX[s] * A + a is the one-hot of (s, a)
    Q = np.zeros((S, A))
    replay = np.zeros((3000, 4), dtype=np.int64)  # (s, a, s', done) ring
    n_replay = 0
    gamma, explore, converge, horizon = 0.9, 300, 400, 3 * S
    starts = [c for c in CELLS if c != GOAL]
    r_goal = reward.reward_bounds()[1]  # stage N = 1: (1 + 0) / 1 - 2, no dense term

    for ep in range(explore + converge):
        eps = 1.0 if ep < explore else 0.0  # explore, then the converged (greedy) agent
        s, traj = starts[rng.integers(len(starts))], []
        for _ in range(horizon):
            a = int(rng.integers(A)) if rng.random() < eps else int(np.argmax(Q[INDEX[s]]))
            s2 = step(s, a)
            done = s2 == GOAL
            traj.append((INDEX[s], a, done))
            replay[n_replay % len(replay)] = (INDEX[s], a, INDEX[s2], done)
            n_replay += 1
            s = s2
            if done:
                break
        t = torch.tensor(traj)
        nxt = TensorDict({"sa": all_sa[t[:, 0] * A + t[:, 1]], "stage": t[:, 2:3].long()}, batch_size=[len(traj)])
        buffers.add_trajectory(TensorDict({"next": nxt}, batch_size=[len(traj)]))
        if buffers.valid_discriminators().all():
            for _ in range(2):
                out = loss(buffers.sample_discriminator_batch())
                opt.zero_grad(set_to_none=True)
                out["loss_discriminator"].backward()
                opt.step()
        # Q-learning on the learned reward, recomputed from the current discriminator (Algorithm 1)
        with torch.no_grad():
            r_sa = (
                reward.combine(reward.discriminators(all_sa), torch.zeros(S * A, 1, dtype=torch.long))
                .view(S, A)
                .numpy()
            )
        batch = replay[rng.integers(min(n_replay, len(replay)), size=256)]
        for si, a, s2i, done in batch:
            target = r_goal if done else r_sa[si, a] + gamma * Q[s2i].max()
            Q[si, a] += 0.5 * (target - Q[si, a])

    counts = buffers.stage_counts().tolist()
    assert counts == [capacity, capacity], counts  # both rings full: the success ring has cycled
    # the converged agent takes shortest paths (the analysis' assumption) ...
    dist = shortest_distances()
    for s in starts:
        assert dist[step(s, int(np.argmax(Q[INDEX[s]])))] == dist[s] - 1, f"the agent is not optimal at {s}"
    # ... and greedy on the learned reward R(s, a) alone does too, from every start
    with torch.no_grad():
        r = reward.combine(reward.discriminators(all_sa), torch.zeros(S * A, 1, dtype=torch.long)).view(S, A)
    for start in starts:
        s, n = start, 0
        while s != GOAL and n <= S:
            s = step(s, int(torch.argmax(r[INDEX[s]])))
            n += 1
        assert s == GOAL and n == dist[start], f"from {start}: {n} steps, shortest is {dist[start]}"
