"""The three-room navigation task of the DrS paper (Appendix, "Navigation": Setup) as a TorchRL env.

A 17x17 grid (outer wall included) split by two horizontal walls into three rooms stacked
vertically. Each inner wall has one gate, a single free cell. The agent starts at a random cell
of the bottom room. The goal (the paper's star) is at a random cell of the top room. The paper's
figure of the two maps is not in its source, so the layout is ours. The *train* and *test* maps
differ only in the columns of the two gates, as in the paper ("the difference between these two
maps lies in the positions of two gates"). A policy that learned the train map's route therefore
walks into walls on the test map.

Observation (paper: "its xy coordinates, the xy coordinates of the goal, and a 3x3 patch around
itself"): a float vector holding ``x_agent, y_agent, x_goal, y_goal`` (``x = col``,
``y = 16 - row``, so *up* increases ``y``), then the 3x3 patch around the agent (1 = wall,
0 = free; row-major, top row first). The gate positions appear only through the patch. The paper
does not say how it encodes coordinates. Here ``coords="onehot"`` (the default) gives each
coordinate as a one-hot of 17 entries (77 entries in all); small MLPs learn sharp per-cell
decisions from it far faster than from scalars. ``coords="scalar"`` gives each coordinate as one
number scaled to [0, 1] (13 entries in all).

Actions (paper: "moving up, down, left, right, or remaining stationary"): one-hot of 5, in the
order of :data:`ACTIONS`. Moving into a wall leaves the agent where it is.

Reward and stages: the sparse reward of the paper's tabular analysis, 1 on reaching the goal and 0
otherwise. The one stage indicator ``"success"`` (agent on the goal) is emitted for
:class:`~drs_torchrl.transforms.StageIndicator`. An episode terminates on success and is truncated
after ``max_steps`` steps.

The env is batched: ``num_envs`` independent grids step together as tensors, with partial resets
(``"_reset"``) for the envs that finished, as TorchRL's collectors send them.
"""

from __future__ import annotations

import functools

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Binary, Bounded, Categorical, Composite, OneHot, Unbounded
from torchrl.envs import EnvBase

SIZE = 17
ACTIONS = ("up", "down", "left", "right", "stay")
MOVES = torch.tensor([[-1, 0], [1, 0], [0, -1], [0, 1], [0, 0]])  # (d_row, d_col); row 0 is the top
WALL_ROWS = (5, 11)  # the two inner walls: top room rows 1-4, middle 6-10, bottom 12-15
TOP_ROOM = (1, 4)  # inclusive row ranges
MIDDLE_ROOM = (6, 10)
BOTTOM_ROOM = (12, 15)
# gate column of the (upper wall, lower wall). ``test`` swaps the train map's gates end for end (every
# left/right preference learned on the train map is wrong there); ``test_shift3`` / ``test_shift6``
# move both gates 3 / 6 columns towards the middle, so a preference for the train gates' side still
# points the right way (the layouts where the paper's figure caption reasons about the learned reward)
GATES = {"train": (3, 13), "test": (13, 3), "test_shift3": (6, 10), "test_shift6": (9, 7)}
# coordinate encodings: one-hot (17 entries per coordinate), scalar (coordinate / 16), relative:
# the goal's offset from the agent (dx, dy) / 16 only, with no absolute position (an egocentric view
# a reward can read without learning where the train map's gates are), and patch: no coordinates at
# all, only the 3x3 patch (the reward input the paper's maze figure caption describes)
OBS_DIMS = {"onehot": 4 * SIZE + 9, "scalar": 4 + 9, "relative": 2 + 9, "patch": 9}
_PATCH = torch.tensor([(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)])


def make_grid(map_name: str) -> torch.Tensor:
    """Walls of a map as a ``(17, 17)`` bool tensor (True = wall)."""
    if map_name not in GATES:
        raise ValueError(f"unknown maze map {map_name!r}; choose one of {sorted(GATES)}")
    g = torch.zeros(SIZE, SIZE, dtype=torch.bool)
    g[0, :] = g[-1, :] = g[:, 0] = g[:, -1] = True
    for row, gate in zip(WALL_ROWS, GATES[map_name]):
        g[row, :] = True
        g[row, gate] = False
    return g


def room_cells(room: tuple[int, int]) -> torch.Tensor:
    """``(n, 2)`` (row, col) of every cell of a room (rows inclusive, all inner columns)."""
    rows = torch.arange(room[0], room[1] + 1)
    cols = torch.arange(1, SIZE - 1)
    return torch.cartesian_prod(rows, cols)


def free_cells(grid: torch.Tensor) -> torch.Tensor:
    """``(n, 2)`` (row, col) of every free cell of a map."""
    return (~grid).nonzero()


def observation(grid: torch.Tensor, pos: torch.Tensor, goal: torch.Tensor, coords: str = "onehot") -> torch.Tensor:
    """Observation vectors ``(*b, OBS_DIMS[coords])`` for agent cells ``pos`` and goal cells ``goal``
    (``(*b, 2)`` row, col)."""
    cells = pos.unsqueeze(-2) + _PATCH  # (*b, 9, 2)
    patch = grid[cells[..., 0].clamp(0, SIZE - 1), cells[..., 1].clamp(0, SIZE - 1)].float()
    return torch.cat([encode_coords(pos, goal, coords), patch], -1)


def encode_coords(pos: torch.Tensor, goal: torch.Tensor, coords: str) -> torch.Tensor:
    """The coordinate part of an observation: x = column, y = 16 - row, for agent then goal."""
    xy = torch.stack([pos[..., 1], SIZE - 1 - pos[..., 0], goal[..., 1], SIZE - 1 - goal[..., 0]], -1)  # (*b, 4)
    if coords == "onehot":
        return torch.nn.functional.one_hot(xy, SIZE).flatten(-2).float()
    if coords == "scalar":
        return xy.float() / float(SIZE - 1)
    if coords == "relative":
        return (xy[..., 2:] - xy[..., :2]).float() / float(SIZE - 1)
    if coords == "patch":
        return xy.new_zeros((*xy.shape[:-1], 0), dtype=torch.float32)
    raise ValueError(f"coords must be one of {sorted(OBS_DIMS)}, got {coords!r}")


def decode_cells(obs: torch.Tensor, coords: str) -> tuple[torch.Tensor, torch.Tensor]:
    """Agent and goal cells ``(*b, 2)`` (row, col) from observations with absolute coordinates."""
    if coords == "onehot":
        xy = obs[..., : 4 * SIZE].unflatten(-1, (4, SIZE)).argmax(-1)
    elif coords == "scalar":
        xy = (obs[..., :4] * (SIZE - 1)).round().long()
    else:
        raise ValueError(f"cells can only be decoded from absolute coordinates (onehot, scalar), not {coords!r}")
    pos = torch.stack([SIZE - 1 - xy[..., 1], xy[..., 0]], -1)
    goal = torch.stack([SIZE - 1 - xy[..., 3], xy[..., 2]], -1)
    return pos, goal


def convert_observation(obs: torch.Tensor, src: str, dst: str) -> torch.Tensor:
    """Re-encode observations from coordinate encoding ``src`` to ``dst`` (the 3x3 patch is kept)."""
    if src == dst:
        return obs
    if dst == "patch":
        return obs[..., -9:]
    pos, goal = decode_cells(obs, src)
    return torch.cat([encode_coords(pos, goal, dst), obs[..., -9:]], -1)


class ThreeRoomMaze(EnvBase):
    """The paper's navigation task, ``num_envs`` grids at once (see the module docstring).

    Args:
        map_name: ``"train"`` or ``"test"`` (the gate positions, :data:`GATES`).
        num_envs: number of grids stepped together (the env's batch size).
        max_steps: episode length limit (truncation).
        seed: seed of the env's own random generator (starts and goals).
        coords: ``"onehot"``, ``"scalar"``, ``"relative"`` or ``"patch"`` (none) encoding of the coordinates (:data:`OBS_DIMS`).
        dense_coef: 0 (default) gives the sparse reward. Above 0, the human-engineered dense baseline:
            ``success - dense_coef * d(s') / d_max`` with ``d`` the shortest-path distance to the goal
            on this map (breadth-first) and ``d_max`` its largest value, i.e. a per-step cost that
            shrinks towards the goal. (A potential difference ``d(s) - d(s')`` telescopes along any
            path, so it would leave the sparse reward's tiny action gaps.)
    """

    _has_dynamic_specs = False

    def __init__(
        self,
        map_name: str = "train",
        num_envs: int = 16,
        max_steps: int = 100,
        seed: int | None = None,
        coords: str = "onehot",
        dense_coef: float = 0.0,
        device="cpu",
    ):
        super().__init__(batch_size=torch.Size([num_envs]), device=device)
        if max_steps < 1:
            raise ValueError("max_steps must be >= 1")
        if coords not in OBS_DIMS:
            raise ValueError(f"coords must be one of {sorted(OBS_DIMS)}, got {coords!r}")
        self.map_name = map_name
        self.coords = coords
        self.obs_dim = OBS_DIMS[coords]
        self.grid = make_grid(map_name)
        self.max_steps = int(max_steps)
        self.num_envs = int(num_envs)
        self.start_cells = room_cells(BOTTOM_ROOM)
        self.goal_cells = room_cells(TOP_ROOM)
        self.rng = torch.Generator()
        self.rng.manual_seed(0 if seed is None else int(seed))
        n = self.num_envs
        self.pos = torch.zeros(n, 2, dtype=torch.long)
        self.goal = torch.zeros(n, 2, dtype=torch.long)
        self.dense_coef = float(dense_coef)
        self._dist = self._dist_max = None
        if self.dense_coef:  # (goal row, goal col, row, col) -> shortest-path distance, for the dense baseline
            self._dist = torch.full((SIZE, SIZE, SIZE, SIZE), -1, dtype=torch.long)
            self._dist[self.goal_cells[:, 0], self.goal_cells[:, 1]] = self.shortest_distances()
            self._dist_max = float(self._dist.max())
        self.t = torch.zeros(n, dtype=torch.long)
        self.observation_spec = Composite(
            observation=Bounded(
                -1.0 if coords == "relative" else 0.0, 1.0, shape=(n, self.obs_dim), dtype=torch.float32
            ),
            success=Binary(n=1, shape=(n, 1), dtype=torch.bool),
            shape=(n,),
        )
        self.action_spec = OneHot(len(ACTIONS), shape=(n, len(ACTIONS)), dtype=torch.bool)
        self.reward_spec = Unbounded(shape=(n, 1), dtype=torch.float32)
        self.done_spec = Composite(
            done=Categorical(2, shape=(n, 1), dtype=torch.bool),
            terminated=Categorical(2, shape=(n, 1), dtype=torch.bool),
            truncated=Categorical(2, shape=(n, 1), dtype=torch.bool),
            shape=(n,),
        )

    def _set_seed(self, seed: int | None) -> None:
        self.rng.manual_seed(0 if seed is None else int(seed))

    def _obs(self) -> torch.Tensor:
        return observation(self.grid, self.pos, self.goal, self.coords)

    def _reset(self, tensordict: TensorDictBase | None, **kwargs) -> TensorDictBase:
        n = self.num_envs
        mask = None if tensordict is None else tensordict.get("_reset", None)
        mask = torch.ones(n, dtype=torch.bool) if mask is None else mask.reshape(n).to(torch.bool)
        k = int(mask.sum())
        if k:
            self.pos[mask] = self.start_cells[torch.randint(len(self.start_cells), (k,), generator=self.rng)]
            self.goal[mask] = self.goal_cells[torch.randint(len(self.goal_cells), (k,), generator=self.rng)]
            self.t[mask] = 0
        false = torch.zeros(n, 1, dtype=torch.bool)
        return TensorDict(
            {
                "observation": self._obs(),
                "success": false.clone(),
                "done": false.clone(),
                "terminated": false.clone(),
                "truncated": false.clone(),
            },
            batch_size=self.batch_size,
        )

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        a = tensordict.get("action").to(torch.float32).argmax(-1)
        target = self.pos + MOVES[a]
        blocked = self.grid[target[:, 0], target[:, 1]]
        self.pos = torch.where(blocked.unsqueeze(-1), self.pos, target)
        self.t += 1
        success = (self.pos == self.goal).all(-1, keepdim=True)
        reward = success.float()
        if self._dist is not None:
            d = self._dist[self.goal[:, 0], self.goal[:, 1], self.pos[:, 0], self.pos[:, 1]].float()
            reward = reward - self.dense_coef * (d / self._dist_max).unsqueeze(-1)
        truncated = (self.t >= self.max_steps).unsqueeze(-1) & ~success
        return TensorDict(
            {
                "observation": self._obs(),
                "success": success,
                "reward": reward,
                "done": success | truncated,
                "terminated": success.clone(),
                "truncated": truncated,
            },
            batch_size=self.batch_size,
        )

    def shortest_distances(self) -> torch.Tensor:
        """Breadth-first distances (steps) from every cell to every goal cell: ``(n_goals, 17, 17)``,
        -1 for walls. The goal cells are :attr:`goal_cells` in order."""
        return _shortest_distances(self.map_name).clone()

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(map={self.map_name!r}, gates={GATES[self.map_name]}, num_envs={self.num_envs}, "
            f"max_steps={self.max_steps}, coords={self.coords!r})"
        )


@functools.lru_cache(maxsize=None)
def _shortest_distances(map_name: str) -> torch.Tensor:
    """:meth:`ThreeRoomMaze.shortest_distances` of a map, computed once per process (a BFS per goal)."""
    free = (~make_grid(map_name)).tolist()  # python lists: a BFS reads single cells, which tensors make slow
    goal_cells = room_cells(TOP_ROOM).tolist()
    moves = MOVES[:4].tolist()
    out = []
    for gr, gc in goal_cells:
        d = [[-1] * SIZE for _ in range(SIZE)]
        d[gr][gc] = 0
        frontier = [(gr, gc)]
        while frontier:
            nxt = []
            for r, c in frontier:
                for dr, dc in moves:
                    rr, cc = r + dr, c + dc
                    if free[rr][cc] and d[rr][cc] < 0:
                        d[rr][cc] = d[r][c] + 1
                        nxt.append((rr, cc))
            frontier = nxt
        out.append(d)
    out = torch.tensor(out, dtype=torch.long)
    return out
