"""The navigation family's pieces (Appendix, "Navigation"): the maze with its stage label and reward slot, the
shortest-path demonstrations (Algorithm 1, line 3), the (s, a) episodes its stage buffers file, its reward on
transitions, and greedy evaluation over a batch of grids.

The maze is not a :class:`~drs_torchrl.tasks.TaskFamily`: its env is the native TorchRL
:class:`~drs_torchrl.envs.maze.ThreeRoomMaze` (batched grids), not a ManiSkill or gymnasium id, so it is built here
rather than by :func:`~drs_torchrl.envs.factory.make_family_env`. Each function takes plain arguments; ``drs-maze``
(:mod:`drs_torchrl.apps.maze`) wires them from ``conf/maze.yaml``.
"""

from __future__ import annotations

import functools

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.envs import TransformedEnv
from torchrl.envs.transforms import RewardScaling
from torchrl.envs.utils import ExplorationType, set_exploration_type

from drs_torchrl.envs.maze import ACTIONS, MOVES, OBS_DIMS, ThreeRoomMaze, convert_observation, observation
from drs_torchrl.runtime.errors import UserError
from drs_torchrl.transforms import ClassifierReward, DrSReward, SemiSparseReward, StageIndicator, StateActionReward

FAMILY = "three_room_maze"  # the family name a maze reward's checkpoint records
REWARD_INPUTS = ("state_action", "next_state")  # R(s, a) as the appendix's tabular analysis, or R(s') as Sec. 4.3


class MazeConfigError(UserError, ValueError):
    """A ``drs-maze`` setting that cannot work, with the fix in its message."""


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


def convertible(src: str, dst: str) -> bool:
    """Whether observations in the ``src`` coordinate encoding can be re-encoded to ``dst`` (absolute positions
    cannot be recovered from relative ones)."""
    return src == dst or src in ("onehot", "scalar") or dst == "patch"


def reward_transform(reward, obs_coords: str | None = None, scale: float = 1.0) -> StateActionReward:
    """The maze's reward on transitions (:class:`~drs_torchrl.transforms.StateActionReward`), the env's observations
    (coordinate encoding ``obs_coords``) re-encoded to those the reward was learned on (e.g. ``relative``)."""
    to = None
    if obs_coords is not None and not isinstance(reward, ClassifierReward):
        learned_on = reward_coords(reward)
        if learned_on != obs_coords:
            to = functools.partial(convert_observation, src=obs_coords, dst=learned_on)
    return StateActionReward(reward, scale=scale, observation_map=to)


def sa_trajectory(
    episode: TensorDictBase,
    stage_key: str = "stage",
    obs_coords: str | None = None,
    reward_coords: str | None = None,
    next_state: bool = False,
) -> TensorDict:
    """An episode as :meth:`StageBuffers.add_trajectory` reads it: per step, the pair ``(s, a)``
    (or ``s'`` alone with ``next_state``) and the stage of ``s'``, under ``"next"``; observations
    re-encoded from ``obs_coords`` to ``reward_coords`` when both are given."""
    obs = episode.get(("next", "observation") if next_state else "observation")
    if obs_coords is not None and reward_coords is not None:
        obs = convert_observation(obs, obs_coords, reward_coords)
    inner = TensorDict(
        {
            "observation": obs,
            "action": episode.get("action").to(torch.float32),
            stage_key: episode.get(("next", stage_key)),
        },
        batch_size=episode.batch_size,
    )
    return TensorDict({"next": inner}, batch_size=episode.batch_size)


def make_env(
    map_name: str,
    num_envs: int,
    max_steps: int,
    seed: int,
    reward_name: str,
    coords: str = "onehot",
    drs: DrSReward | None = None,
    dense_coef: float = 1.0,
    reward_scale: float = 1.0,
) -> TransformedEnv:
    """The maze with its stage label; ``semi_sparse`` writes ``k - 1`` as the env reward, ``dense``
    the env's distance-shaped reward (``dense_coef``), and a given DrS reward writes ``R(s, a)``.
    ``reward_scale`` != 1 appends TorchRL's ``RewardScaling`` (the reward the agent trains on)."""
    env = TransformedEnv(
        ThreeRoomMaze(
            map_name,
            num_envs=num_envs,
            max_steps=max_steps,
            seed=seed,
            coords=coords,
            dense_coef=dense_coef if reward_name == "dense" else 0.0,
        ),
        StageIndicator(["success"], indicators_key=None),
    )
    if reward_name == "semi_sparse":  # scaled here: TorchRL's RewardScaling refuses its bounded reward spec
        env.append_transform(SemiSparseReward(1, offset=-1.0, scale=reward_scale))
    if drs is not None:
        env.append_transform(reward_transform(drs, coords))
    if reward_scale != 1.0 and reward_name != "semi_sparse":
        env.append_transform(RewardScaling(loc=0.0, scale=float(reward_scale)))
    return env


def evaluate_greedy(actor, env: TransformedEnv) -> dict[str, float]:
    """One greedy episode in each of the env's grids: success rate and mean episode length."""
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        td = env.rollout(env.base_env.max_steps, actor, break_when_any_done=False)
    done = td.get(("next", "done")).squeeze(-1)  # (n, T)
    first = done.float().argmax(-1)
    idx = torch.arange(done.shape[0])
    success = td.get(("next", "success")).squeeze(-1)[idx, first]
    return {"eval_success": float(success.float().mean()), "eval_length": float((first + 1).float().mean())}


def demo_episodes(
    map_name: str, n: int, seed: int, coords: str = "onehot", next_state: bool = False
) -> list[TensorDict]:
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
        out.append(
            TensorDict(
                {
                    "next": TensorDict(
                        {"observation": torch.stack(obs), "action": torch.stack(acts), "stage": stage},
                        batch_size=[len(obs)],
                    )
                },
                batch_size=[len(obs)],
            )
        )
    return out
