"""``drs-maze``: the paper's navigation experiment (Appendix, "Navigation"), one-stage DrS with DQN.

Phase 1 (``phase=learn``, train map) runs Algorithm 1 with one stage (success). A DQN agent trains
on the learned reward. Every finished episode goes into the stage buffers, and the discriminator
learns "comes from a successful episode" vs "from a failed one". As in the appendix, the reward is
a function of the state-action pair (the paper's tabular analysis writes
``R(s, a) = tanh(D(s, a))``). The discriminator reads the observation concatenated with the one-hot
action, and the reward of a transition is the rescaled Eq. 4 with the stage of its next state:
``k + alpha * tanh(D(s, a)) - 2``. A failed step then earns about -2 and the success step -1.
Phase 2 (``phase=reuse``, test map, moved gates) trains a fresh DQN agent with the frozen reward
(``reward.name=drs reward.checkpoint=.../reward.pt``). The baselines in the same slot are
``sparse`` (1 on success, the paper's baseline) and ``semi_sparse`` (``k - 1``: -1 a step, 0 on
success, which is the constant part of the DrS reward without the learned term) and ``dense``
(human-engineered: ``success - d(s') / d_max`` with ``d`` the map's shortest-path distance to the goal).
``phase=report`` gathers the runs under ``report.root`` into a curve PNG, a CSV and a Markdown table.

Choices the paper leaves open, or where this script departs from it (all in ``conf/maze.yaml``):

* Demonstrations (Algorithm 1, line 3, optional in the paper): ``demos=100`` shortest-path
  episodes of the train map go into the success buffer. Without them, epsilon-greedy DQN on this
  map met no success in 300k steps of phase 1 (a uniform random walk succeeds in about 0.15% of
  200-step episodes), so the discriminator never trained.
* n-step TD targets (``dqn.n_steps``, TorchRL's ``MultiStepTransform``) for every reward, so that
  the goal's value travels back along 30-50-step routes within a CPU budget. The n-step sums are
  made when transitions are stored, so in phase 1 the env writes ``R(s, a)`` with the discriminator
  of that moment. With ``dqn.n_steps=1`` the reward is instead recomputed from the current
  discriminator whenever the agent samples, as in Algorithm 1.
* ``train_success`` (in ``train.csv``) is the success rate of the last 100 *finished* training
  episodes. Successful episodes end early and so finish more often, which biases this rate upward.
  ``eval_success`` (one greedy episode in each of ``eval.episodes`` grids) is the unbiased figure.

It is a thin script over TorchRL pieces: the batched :class:`~drs_torchrl.envs.maze.ThreeRoomMaze`
with a :class:`~drs_torchrl.transforms.StageIndicator`, a ``Collector``, a ``ReplayBuffer`` whose
sampling transform recomputes the learned reward from the current discriminator, a ``QValueActor``
with an ``EGreedyModule``, ``DQNLoss`` and a ``SoftUpdate``/``HardUpdate`` target network. The
project's ``StageBuffers``, ``DiscriminatorLoss`` and ``DrSReward`` supply the DrS parts.
"""
from __future__ import annotations

import csv
import json
import os
import sys
import time
from collections import deque
from pathlib import Path

import hydra
import numpy as np
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate
from omegaconf import DictConfig, ListConfig, OmegaConf
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictSequential
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.envs import TransformedEnv
from torchrl.envs.transforms import MultiStepTransform, RewardScaling, Transform
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MLP, EGreedyModule, QValueActor
from torchrl.objectives import DQNLoss, ValueEstimators

from drs_torchrl.data import StageBuffers, TrajectoryAssembler
from drs_torchrl.envs.maze import (
    ACTIONS,
    convert_observation,
    GATES,
    MOVES,
    OBS_DIMS,
    SIZE,
    ThreeRoomMaze,
    free_cells,
    make_grid,
    observation,
)
from drs_torchrl.objectives import DiscriminatorLoss
from drs_torchrl.transforms import DrSReward, StageIndicator

REWARDS = ("drs", "sparse", "semi_sparse", "dense")
REWARD_INPUTS = ("state_action", "next_state")  # R(s, a) as the appendix's tabular analysis, or R(s') as Sec. 4.3
FAMILY = "three_room_maze"
RB_KEYS = ["observation", "action", ("next", "observation"), ("next", "reward"), ("next", "done"),
           ("next", "terminated"), ("next", "truncated"), ("next", "stage")]
# n-step targets: whether the observation a window ends on is terminal (see terminal_at_window_end)
TERMINAL_AT_OBS = ("next", "terminal_obs")


def mark_terminal_obs(batch: TensorDictBase) -> TensorDictBase:
    """Copy ``("next", "terminated")`` to :data:`TERMINAL_AT_OBS` before n-step windows are formed.

    TorchRL 0.14's ``MultiStepTransform`` cuts a window at the episode's end and gathers the
    ``"next"`` entries of the window's last step, *except* the done keys, which stay those of the
    window's first step. A window that reaches the goal a few steps ahead therefore ends on the
    terminal observation with ``terminated=False``, and the TD target bootstraps from the value of
    a state that has none. A copy under another name is gathered with the observation, so it says
    whether the observation the window ends on is terminal.
    """
    batch.set(TERMINAL_AT_OBS, batch.get(("next", "terminated")).clone())
    return batch


def terminal_at_window_end(sample: TensorDictBase) -> TensorDictBase:
    """Set ``("next", "terminated")`` (and ``"done"``) of sampled n-step windows from :data:`TERMINAL_AT_OBS`."""
    term = sample.get(TERMINAL_AT_OBS)
    sample.set(("next", "terminated"), term)
    sample.set(("next", "done"), sample.get(("next", "done")) | term)
    return sample


class MazeConfigError(ValueError):
    """A ``drs-maze`` setting that cannot work, with the fix in its message."""


# ----------------------------------------------------------------------------- reward on (s, a)
class StateActionReward(Transform):
    """Write the DrS reward ``R(s, a)`` of transitions into ``("next", "reward")``.

    ``reward`` is a :class:`DrSReward` whose ``reward_in_keys`` (e.g. ``observation`` and
    ``action``) are read at the root of a transition, so they describe ``(s, a)``. The stage index
    is read from ``("next", stage)``, the stage of ``s'``. As a replay-buffer transform
    (``forward``) it recomputes rewards from the current discriminator each time the agent samples
    (Algorithm 1, line 18). Inside a :class:`~torchrl.envs.TransformedEnv` (``_step``, placed after
    the :class:`StageIndicator`) it writes the reward of each step as it is taken.
    ``obs_coords``: the coordinate encoding of the env's observations; when the reward was learned on
    another one (e.g. ``relative``), observations are re-encoded before the reward reads them.
    ``scale`` multiplies the reward the agent sees (``dqn.reward_scale``); the discriminator is
    untouched. A reward learned with ``reward.input=next_state`` (metadata ``reward_on``) reads its
    inputs from ``"next"`` instead: ``R(s')`` as in Sec. 4.3.
    """

    def __init__(self, reward: DrSReward, obs_coords: str | None = None, scale: float = 1.0):
        super().__init__()  # it only rewrites the reward entry, whose spec the env already has
        self.drs = reward
        self.obs_coords = obs_coords
        self.reward_coords = reward_coords(reward)
        self.scale = float(scale)
        self.on_next_state = reads_next_state(reward)

    def _reward(self, root: TensorDictBase, nxt: TensorDictBase) -> torch.Tensor:
        src = nxt if self.on_next_state else root
        sa = TensorDict({k: src.get(k) for k in self.drs.reward_in_keys}, batch_size=root.batch_size)
        if self.obs_coords is not None and self.obs_coords != self.reward_coords:
            sa.set("observation", convert_observation(sa.get("observation"), self.obs_coords, self.reward_coords))
        sa.set(self.drs.stage_key, nxt.get(self.drs.stage_key))
        r = self.drs.reward(sa)
        return r * self.scale if self.scale != 1.0 else r

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        tensordict.set(("next", self.drs.reward_key), self._reward(tensordict, tensordict.get("next")))
        return tensordict

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        next_tensordict.set(self.drs.reward_key, self._reward(tensordict, next_tensordict))
        return next_tensordict


def sa_trajectory(episode: TensorDictBase, stage_key: str = "stage", obs_coords: str | None = None,
                  reward_coords: str | None = None, next_state: bool = False) -> TensorDict:
    """An episode as :meth:`StageBuffers.add_trajectory` reads it: per step, the pair ``(s, a)``
    (or ``s'`` alone with ``next_state``) and the stage of ``s'``, under ``"next"``; observations
    re-encoded from ``obs_coords`` to ``reward_coords`` when both are given."""
    obs = episode.get(("next", "observation") if next_state else "observation")
    if obs_coords is not None and reward_coords is not None:
        obs = convert_observation(obs, obs_coords, reward_coords)
    inner = TensorDict(
        {"observation": obs, "action": episode.get("action").to(torch.float32),
         stage_key: episode.get(("next", stage_key))},
        batch_size=episode.batch_size,
    )
    return TensorDict({"next": inner}, batch_size=episode.batch_size)


def reads_next_state(reward: DrSReward) -> bool:
    """Whether a maze reward reads ``s'`` (``reward.input=next_state``) rather than ``(s, a)``."""
    return reward.metadata.get("reward_on") == "next_state"


def reward_coords(reward: DrSReward) -> str:
    """The coordinate encoding a maze reward was learned with (from its input size)."""
    dim = reward.in_shapes["observation"]
    for coords, d in OBS_DIMS.items():
        if d == dim:
            return coords
    raise MazeConfigError(f"a maze reward reads observations of size {sorted(OBS_DIMS.values())}, this one {dim}")


def all_state_actions(map_name: str, goal: tuple[int, int], coords: str = "onehot",
                      next_state: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
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
    with torch.no_grad():
        logits = reward.discriminators(feats)
        r = reward.combine(logits, torch.zeros(*logits.shape[:-1], 1, dtype=torch.long)).squeeze(-1)
    return cells, r


def reward_diagnostics(reward: DrSReward, map_name: str, max_steps: int) -> dict[str, float]:
    """How well the reward alone points the way on a map (the appendix's tabular property).

    ``optimal_action_rate``: fraction of (cell, goal) pairs, over every top-room goal and every free
    cell but the goal, where ``argmax_a R(s, a)`` is a shortest-path action. ``greedy_success``:
    fraction of (bottom-room start, goal) pairs from which following ``argmax_a R(s, a)`` reaches
    the goal within ``max_steps``.
    """
    env = ThreeRoomMaze(map_name, num_envs=1)
    dist = env.shortest_distances()  # (goals, 17, 17)
    grid = env.grid
    n_opt = n_all = 0
    greedy = []
    for gi, goal in enumerate(env.goal_cells.tolist()):
        cells, r = dense_reward_table(reward, map_name, tuple(goal))
        best = r.argmax(-1)
        d = dist[gi]
        nxt = cells + MOVES[best]
        blocked = grid[nxt[:, 0], nxt[:, 1]]
        nxt = torch.where(blocked.unsqueeze(-1), cells, nxt)
        not_goal = (cells != torch.tensor(goal)).any(-1)
        optimal = d[nxt[:, 0], nxt[:, 1]] == d[cells[:, 0], cells[:, 1]] - 1
        n_opt += int((optimal & not_goal).sum())
        n_all += int(not_goal.sum())
        table = torch.full((SIZE, SIZE), 4, dtype=torch.long)
        table[cells[:, 0], cells[:, 1]] = best
        pos = env.start_cells.clone()
        done = torch.zeros(len(pos), dtype=torch.bool)
        for _ in range(max_steps):
            a = table[pos[:, 0], pos[:, 1]]
            tgt = pos + MOVES[a]
            pos = torch.where(grid[tgt[:, 0], tgt[:, 1]].unsqueeze(-1), pos, tgt)
            done |= (pos == torch.tensor(goal)).all(-1)
        greedy.append(done.float().mean())
    return {"optimal_action_rate": n_opt / max(n_all, 1), "greedy_success": float(torch.stack(greedy).mean())}


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
    fig.suptitle("Learned reward R(s, a) per cell (lighter = higher): up / down / left / right on that side of the cell,\n"
                 "stay in the middle; red box = goal")
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# ----------------------------------------------------------------------------- building blocks
def make_env(map_name: str, num_envs: int, max_steps: int, seed: int, reward_name: str, coords: str = "onehot",
             drs: DrSReward | None = None, dense_coef: float = 1.0, reward_scale: float = 1.0) -> TransformedEnv:
    """The maze with its stage label; ``semi_sparse`` writes ``k - 1`` as the env reward, ``dense``
    the env's distance-shaped reward (``dense_coef``), and a given DrS reward writes ``R(s, a)``.
    ``reward_scale`` != 1 appends TorchRL's ``RewardScaling`` (the reward the agent trains on)."""
    env = TransformedEnv(
        ThreeRoomMaze(map_name, num_envs=num_envs, max_steps=max_steps, seed=seed, coords=coords,
                      dense_coef=dense_coef if reward_name == "dense" else 0.0),
        StageIndicator(["success"], indicators_key=None, semi_sparse_reward=reward_name == "semi_sparse", semi_sparse_offset=-1.0),
    )
    if drs is not None:
        env.append_transform(StateActionReward(drs, coords))
    if reward_scale != 1.0:
        env.append_transform(RewardScaling(loc=0.0, scale=float(reward_scale)))
    return env


def make_qnet(cfg: DictConfig, action_spec) -> QValueActor:
    net = MLP(in_features=OBS_DIMS[cfg.coords], out_features=len(ACTIONS), num_cells=list(cfg.dqn.hidden), activation_class=torch.nn.ReLU)
    return QValueActor(net, in_keys=["observation"], spec=action_spec)


def evaluate(actor, env: TransformedEnv) -> dict[str, float]:
    """One greedy episode in each of the env's grids: success rate and mean episode length."""
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        td = env.rollout(env.base_env.max_steps, actor, break_when_any_done=False)
    done = td.get(("next", "done")).squeeze(-1)  # (n, T)
    first = done.float().argmax(-1)
    idx = torch.arange(done.shape[0])
    success = td.get(("next", "success")).squeeze(-1)[idx, first]
    return {"eval_success": float(success.float().mean()), "eval_length": float((first + 1).float().mean())}


def demo_episodes(map_name: str, n: int, seed: int, coords: str = "onehot", next_state: bool = False) -> list[TensorDict]:
    """``n`` shortest-path episodes on a map (Algorithm 1, line 3: optional demonstrations for the
    success buffer), from random bottom-room starts to random top-room goals. Per step the
    observation of ``s`` (of ``s'`` with ``next_state``), the action and the stage of ``s'``."""
    env = ThreeRoomMaze(map_name, num_envs=1, seed=seed)
    dist = env.shortest_distances()
    g = torch.Generator().manual_seed(seed)
    out = []
    for _ in range(n):
        s = env.start_cells[torch.randint(len(env.start_cells), (1,), generator=g)].reshape(2)
        gi = int(torch.randint(len(env.goal_cells), (1,), generator=g))
        goal, d = env.goal_cells[gi], dist[gi]
        obs, acts = [], []
        while not torch.equal(s, goal):
            for a in torch.randperm(4, generator=g).tolist():  # a random one of the shortest moves
                t = s + MOVES[a]
                if d[t[0], t[1]] == d[s[0], s[1]] - 1:
                    break
            obs.append(observation(env.grid, t if next_state else s, goal, coords))
            acts.append(torch.nn.functional.one_hot(torch.tensor(a), len(ACTIONS)).float())
            s = t
        stage = torch.zeros(len(obs), 1, dtype=torch.long)
        stage[-1] = 1
        out.append(TensorDict({"next": TensorDict({"observation": torch.stack(obs), "action": torch.stack(acts), "stage": stage}, batch_size=[len(obs)])}, batch_size=[len(obs)]))
    return out


def _convertible(src: str, dst: str) -> bool:
    return src == dst or src in ("onehot", "scalar") or dst == "patch"


def validate(cfg: DictConfig) -> None:
    checks = [
        (cfg.phase in ("learn", "reuse", "report"), f"phase must be learn, reuse or report, got {cfg.phase!r}"),
        (cfg.reward.name in REWARDS, f"reward.name must be one of {REWARDS}, got {cfg.reward.name!r}"),
        (cfg.phase != "learn" or cfg.reward.name == "drs", "phase=learn learns the DrS reward: use reward.name=drs (baselines run with phase=reuse)"),
        (cfg.phase != "learn" or not cfg.reward.checkpoint, "reward.checkpoint is for phase=reuse"),
        (cfg.phase != "reuse" or cfg.reward.name != "drs" or bool(cfg.reward.checkpoint), "phase=reuse with reward.name=drs needs reward.checkpoint=PATH (a reward.pt written by phase=learn)"),
        (cfg.map is None or cfg.map in GATES, f"map must be null or one of {sorted(GATES)}, got {cfg.map!r}"),
        (cfg.total_frames > 0 and cfg.num_envs > 0 and cfg.max_steps > 0, "total_frames, num_envs and max_steps must be > 0"),
        (cfg.dqn.frames_per_batch % cfg.num_envs == 0, f"dqn.frames_per_batch ({cfg.dqn.frames_per_batch}) must be a multiple of num_envs ({cfg.num_envs})"),
        (cfg.dqn.utd > 0 and cfg.dqn.batch_size > 0, "dqn.utd and dqn.batch_size must be > 0"),
        (0 < cfg.dqn.gamma <= 1, "dqn.gamma must be in (0, 1]"),
        (cfg.dqn.n_steps >= 1, "dqn.n_steps must be >= 1"),
        (cfg.dqn.get("reward_scale", 1.0) > 0, "dqn.reward_scale must be > 0 (it multiplies the reward the agent trains on)"),
        (cfg.eval.interval > 0 and cfg.eval.episodes > 0, "eval.interval and eval.episodes must be > 0"),
        (cfg.demos >= 0, "demos must be >= 0"),
        (cfg.reward.get("input", "state_action") in REWARD_INPUTS,
         f"reward.input must be one of {REWARD_INPUTS}, got {cfg.reward.get('input')!r}"),
        (cfg.reward.get("positives", "all") in ("all", "demos"), f"reward.positives must be all or demos, got {cfg.reward.get('positives')!r}"),
        (cfg.reward.get("positives", "all") != "demos" or cfg.demos > 0,
         "reward.positives=demos makes the demonstrations the only positives: set demos > 0"),
        (cfg.reward.get("reuse_alpha") is None or 0 <= float(cfg.reward.reuse_alpha) < 0.5,
         "reward.reuse_alpha must be null or in [0, 0.5) (0 keeps only DrS's constant part)"),
        (cfg.coords in OBS_DIMS, f"coords must be one of {sorted(OBS_DIMS)}, got {cfg.coords!r}"),
        (cfg.reward.get("coords") in (None, *OBS_DIMS), f"reward.coords must be null or one of {sorted(OBS_DIMS)}, got {cfg.reward.get('coords')!r}"),
        (_convertible(cfg.coords, cfg.reward.get("coords") or cfg.coords),
         f"a reward on coords={cfg.reward.get('coords')} cannot read the agent's coords={cfg.coords} observations "
         "(absolute positions cannot be recovered from relative ones): use reward.coords=relative, patch or null"),
    ]
    bad = [msg for ok, msg in checks if not ok]
    if bad:
        raise MazeConfigError("; ".join(bad))


# ----------------------------------------------------------------------------- training
def train(cfg: DictConfig, run_dir: str | os.PathLike) -> dict:
    """Phase 1 or phase 2 (or a baseline) of the maze experiment; writes into ``run_dir``."""
    validate(cfg)
    run_dir = Path(run_dir)
    torch.set_num_threads(int(cfg.num_threads))
    torch.manual_seed(int(cfg.seed))
    np.random.seed(int(cfg.seed))
    learn = cfg.phase == "learn"
    map_name = cfg.map or ("train" if learn else "test")
    rname = cfg.reward.name

    d = cfg.dqn
    n_steps = int(d.n_steps)

    # reward: learned in this run, frozen from a checkpoint, or a baseline written by the env
    drs = buffers = disc_loss = disc_opt = rc = None  # rc: the coordinate encoding the learned reward reads
    if rname == "drs":
        r = cfg.reward
        if learn:
            rc = r.get("coords") or cfg.coords
            on_next = r.get("input", "state_action") == "next_state"
            keys = ["observation"] if on_next else ["observation", "action"]
            drs = DrSReward(1, keys, {"observation": OBS_DIMS[rc], "action": len(ACTIONS)} if not on_next else {"observation": OBS_DIMS[rc]},
                            formula=r.formula, alpha=r.alpha, offset=r.offset, hidden=list(r.hidden), activation=r.activation,
                            metadata={"family": FAMILY, "map": map_name, "reward_on": "next_state" if on_next else "state_action",
                                      "coords": rc, "seed": int(cfg.seed), "positives": r.get("positives", "all")})
            buffers = StageBuffers(1, keys, capacity=r.stage_buffer_size, batch_size=r.disc.batch_size)
            disc_loss = DiscriminatorLoss(drs.discriminators, keys, early_stop_threshold=r.disc.early_stop_threshold,
                                          window=r.disc.window)
            disc_opt = torch.optim.Adam(drs.discriminators.parameters(), lr=r.disc.lr)
            for ep in demo_episodes(map_name, int(cfg.demos), int(cfg.seed), rc, on_next) if cfg.demos else []:
                buffers.add_trajectory(ep, demo=True)
        else:
            drs = DrSReward.from_checkpoint(r.checkpoint)
            meta = drs.metadata
            if meta.get("family") != FAMILY or drs.num_stages != 1 or drs.reward_in_keys not in (["observation", "action"], ["observation"]):
                raise MazeConfigError(f"{r.checkpoint} is not a maze reward (family {meta.get('family')!r}, inputs {drs.reward_in_keys})")
            if not _convertible(cfg.coords, reward_coords(drs)):
                raise MazeConfigError(f"{r.checkpoint} was learned with coords={reward_coords(drs)}, which this run's "
                                      f"coords={cfg.coords} observations cannot be re-encoded to; use coords={reward_coords(drs)}")
            if r.get("reuse_offset") is not None:  # shift the frozen reward (the learned term is unchanged)
                drs.offset = float(r.reuse_offset)
            if r.get("reuse_alpha") is not None:  # reweight the learned term; 0 leaves DrS's constant part (the control)
                drs.alpha = float(r.reuse_alpha)
            drs.requires_grad_(False)
    # the run directory is written only once the reward (and its checkpoint) is known to be usable
    run_dir.mkdir(parents=True, exist_ok=True)
    OmegaConf.save(cfg, run_dir / "config.yaml", resolve=True)
    # 1-step TD: the DrS reward is recomputed from the current discriminator when the agent samples
    # (Algorithm 1). n-step TD: rewards are summed when the transitions are stored, so the env
    # writes R(s, a) with the discriminator of the moment (see the module docstring).
    env_drs = drs if (drs is not None and n_steps > 1) else None
    scale = float(d.get("reward_scale", 1.0))
    env = make_env(map_name, cfg.num_envs, cfg.max_steps, cfg.seed, rname, cfg.coords, env_drs, float(cfg.reward.dense_coef), scale)
    eval_env = make_env(map_name, cfg.eval.episodes, cfg.max_steps, cfg.seed + 10_000, rname, cfg.coords)
    actor = make_qnet(cfg, env.action_spec)
    explore = EGreedyModule(env.action_spec, eps_init=d.eps_init, eps_end=d.eps_end,
                            annealing_num_steps=max(1, int(d.eps_anneal_frac * cfg.total_frames)))
    policy = TensorDictSequential(actor, explore)
    if n_steps > 1:
        rb = ReplayBuffer(storage=LazyTensorStorage(int(d.buffer_size), ndim=2), batch_size=int(d.batch_size),
                          transform=MultiStepTransform(n_steps, float(d.gamma)))
    else:
        rb = ReplayBuffer(storage=LazyTensorStorage(int(d.buffer_size)), batch_size=int(d.batch_size),
                          transform=StateActionReward(drs, cfg.coords, scale) if drs is not None else None)

    loss = DQNLoss(actor, action_space=env.action_spec, delay_value=True, double_dqn=bool(d.double_dqn), loss_function=d.loss_function)
    loss.make_value_estimator(ValueEstimators.TD0, gamma=float(d.gamma))
    target = instantiate(d.target_update)(loss)
    opt = torch.optim.Adam(loss.parameters(), lr=float(d.lr))
    collector = Collector(env, policy, frames_per_batch=int(d.frames_per_batch), total_frames=int(cfg.total_frames),
                          auto_register_policy_transforms=False)
    assembler = TrajectoryAssembler()

    episodes: deque = deque(maxlen=100)
    rows, window, frames, updates, disc_updates, owed = [], _Window(), 0, 0, 0, 0.0
    next_eval = 0
    t0, cpu0 = time.perf_counter(), time.process_time()
    columns = ["frames", "wall_s", "updates", "epsilon", "eval_success", "eval_length", "train_success", "train_length",
               "dqn_loss", "reward_mean"]
    if buffers is not None:
        columns += ["disc_loss", "disc_accuracy", "success_buffer", "failure_buffer", "disc_updates", "disc_active"]
    log_path = run_dir / "train.csv"
    with open(log_path, "w", newline="") as f:
        csv.DictWriter(f, fieldnames=columns).writeheader()

    def log_row():
        row = {"frames": frames, "wall_s": round(time.perf_counter() - t0, 2), "updates": updates, "epsilon": float(explore.eps),
               **evaluate(actor, eval_env)}
        row["train_success"] = float(np.mean([s for s, _ in episodes])) if episodes else float("nan")
        row["train_length"] = float(np.mean([n for _, n in episodes])) if episodes else float("nan")
        row.update(window.flush())
        if buffers is not None:
            counts = buffers.stage_counts()
            row.update(success_buffer=int(counts[1]), failure_buffer=int(counts[0]), disc_updates=disc_updates,
                       disc_active=float(disc_loss.training_mask()[0]))
        with open(log_path, "a", newline="") as f:
            csv.DictWriter(f, fieldnames=columns, restval="nan").writerow(row)
        rows.append(row)
        if cfg.verbose:
            print(f"[{row['wall_s']:7.1f}s] frames {frames:7d}  eval success {row['eval_success']:.2f}  train success "
                  f"{row['train_success']:.2f}  eps {row['epsilon']:.2f}", flush=True)

    try:
        for batch in collector:
            if frames >= next_eval:
                log_row()
                next_eval += int(cfg.eval.interval)
            n = batch.numel()
            frames += n
            if n_steps > 1:
                rb.extend(mark_terminal_obs(batch.select(*RB_KEYS)))
            else:
                rb.extend(batch.reshape(-1).select(*RB_KEYS))
            for ep in assembler.add(batch):
                stage = int(ep.get(("next", "stage")).max())
                episodes.append((stage, ep.shape[0]))
                if buffers is not None:
                    if stage == 0 or cfg.reward.get("positives", "all") == "all":  # positives=demos: agent successes not filed
                        buffers.add_trajectory(sa_trajectory(ep, obs_coords=cfg.coords, reward_coords=rc,
                                                             next_state=reads_next_state(drs)))
                    disc_loss.record_episodes([stage])
            explore.step(n)
            if frames < int(d.learning_starts):
                continue
            owed += float(d.utd) * n
            while owed >= 1:
                owed -= 1
                sample = rb.sample()
                if n_steps > 1:
                    sample = terminal_at_window_end(sample)
                out = loss(sample)
                opt.zero_grad(set_to_none=True)
                out["loss"].backward()
                torch.nn.utils.clip_grad_norm_(loss.parameters(), float(d.grad_clip))
                opt.step()
                target.step()
                updates += 1
                r1 = sample.get(("next", "original_reward"), None) if n_steps > 1 else None
                window.add(dqn_loss=float(out["loss"].detach()), reward_mean=float((r1 if r1 is not None else sample.get(("next", "reward"))).mean()))
                if buffers is not None and buffers.valid_discriminators().all():
                    for _ in range(int(cfg.reward.disc.updates_per_dqn_update)):
                        dout = disc_loss(buffers.sample_discriminator_batch())
                        if dout["loss_discriminator"].requires_grad:
                            disc_opt.zero_grad(set_to_none=True)
                            dout["loss_discriminator"].backward()
                            disc_opt.step()
                            disc_updates += 1
                        window.add(disc_loss=float(dout["loss_0"]), disc_accuracy=float(dout["accuracy_0"]))
        log_row()
    finally:
        collector.shutdown()

    wall = time.perf_counter() - t0
    summary = {
        "phase": cfg.phase, "map": map_name, "reward": rname, "reward_scale": scale, "seed": int(cfg.seed),
        "reward_input": ("next_state" if reads_next_state(drs) else "state_action") if drs is not None else None,
        "reward_alpha": drs.alpha if drs is not None else None,
        "reward_coords": reward_coords(drs) if (drs is not None and reward_coords(drs) != cfg.coords) else None, "frames": frames, "updates": updates,
        "wall_time_s": round(wall, 1), "cpu_time_s": round(time.process_time() - cpu0, 1), "env_steps_per_s": round(frames / wall, 1),
        "final_eval_success": rows[-1]["eval_success"], "final_eval_length": rows[-1]["eval_length"],
        "mean_eval_success_last3": float(np.mean([r["eval_success"] for r in rows[-3:]])),
    }
    torch.save(actor.state_dict(), run_dir / "policy.pt")
    if drs is not None:
        if learn:
            summary["reward_checkpoint"] = str(drs.save(run_dir / "reward.pt"))
            summary["disc_updates"] = disc_updates
            summary["stage_buffer_counts"] = buffers.stage_counts().tolist()
        maps = ("train", map_name if map_name != "train" else "test")
        summary["reward_map"] = str(plot_reward_map(drs, run_dir / "reward_map.png", tuple(cfg.plot_goal), maps))
        summary["reward_diagnostics"] = {m: reward_diagnostics(drs, m, cfg.max_steps) for m in GATES}
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary


class _Window:
    """Means of scalars logged since the last row."""

    def __init__(self):
        self.values: dict[str, list[float]] = {}

    def add(self, **kv):
        for k, v in kv.items():
            self.values.setdefault(k, []).append(v)

    def flush(self) -> dict[str, float]:
        out = {k: float(np.mean(v)) if v else float("nan") for k, v in self.values.items()}
        self.values = {k: [] for k in self.values}
        return out


# ----------------------------------------------------------------------------- report
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
                w.writerow([summ["phase"], summ["map"], reward_label(summ), summ["seed"], r["frames"], r["eval_success"], r["eval_length"], r["train_success"]])
    groups: dict[tuple[str, str], list] = {}
    for summ, rows, d in runs:
        groups.setdefault((summ["phase"], summ["map"], reward_label(summ)), []).append((summ, rows, d))
    many_maps = {ph: len({m for p, m, _ in groups if p == ph}) > 1 for ph, _, _ in groups}
    panels = [("learn", "phase 1: DrS reward learning (train map)"), ("reuse", "phase 2: fresh DQN on the test map")]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    table = ["| phase | map | reward | seeds | env steps | eval success at the end (per seed) | mean +- std | mean over the last 3 evals | wall time per run (s) |",
             "|---|---|---|---|---|---|---|---|---|"]
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
            table.append(f"| {phase} | {members[0][0]['map']} | {rname} | {', '.join(str(m[0]['seed']) for m in members)} | "
                         f"{members[0][0]['frames']} | {', '.join(f'{x:.2f}' for x in finals)} | {np.mean(finals):.2f} +- {np.std(finals):.2f} | "
                         f"{np.mean(last3):.2f} | {np.mean([m[0]['wall_time_s'] for m in members]):.0f} |")
        ax.set_title(title if not many_maps.get(phase) else title.split(" on the ")[0] + " (map in the legend)")
        ax.set_xlabel("env steps")
        ax.set_ylabel("greedy eval success rate")
        ax.set_ylim(-0.05, 1.05)
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left")
    fig.tight_layout()
    fig.savefig(out / "curves.png", dpi=110)
    plt.close(fig)
    diag = ["", "| learned reward (seed) | map | argmax_a R(s,a) is a shortest-path action | greedy on R reaches the goal |", "|---|---|---|---|"]
    for summ, _, _ in runs:
        if summ["phase"] == "learn" and "reward_diagnostics" in summ:
            for m, v in summ["reward_diagnostics"].items():
                diag.append(f"| {reward_label(summ)} {summ['seed']} | {m} | {v['optimal_action_rate']:.2f} | {v['greedy_success']:.2f} |")
    (out / "table.md").write_text("\n".join(table + diag) + "\n")
    return {"runs": len(runs), "out": str(out)}


# ----------------------------------------------------------------------------- CLI
def _conf_dir() -> str:
    env = os.environ.get("DRS_CONF_DIR")
    if env:
        return str(Path(env).resolve())
    for parent in Path(__file__).resolve().parents:
        if (parent / "conf" / "maze.yaml").is_file():
            return str(parent / "conf")
    raise FileNotFoundError("cannot find drs-torchrl's conf/ directory (conf/maze.yaml); set DRS_CONF_DIR=/path/to/conf")


@hydra.main(config_path=_conf_dir(), config_name="maze", version_base=None)
def main(cfg: DictConfig) -> None:
    """``drs-maze phase=learn|reuse|report ...`` (see conf/maze.yaml)."""
    try:
        if cfg.phase == "report":
            res = report(cfg.report.root, cfg.report.out)
            print(f"drs-maze: report of {res['runs']} runs in {res['out']}")
            return
        run_dir = HydraConfig.get().runtime.output_dir
        s = train(cfg, run_dir)
    except (MazeConfigError, ValueError, FileNotFoundError) as exc:
        print(f"drs-maze: error: {exc}", file=sys.stderr)
        sys.exit(2)
    print(f"drs-maze: {s['phase']} on the {s['map']} map with the {s['reward']} reward: {s['frames']} env steps in "
          f"{s['wall_time_s']:.0f}s; greedy eval success {s['final_eval_success']:.2f}; run dir {run_dir}")
    if "reward_checkpoint" in s:
        print(f"  reward checkpoint: {s['reward_checkpoint']}")


if __name__ == "__main__":
    main()
