"""The paper's navigation experiment (Appendix, "Navigation"): the three-room maze env, the reward
on (s, a) and ``drs-maze`` end to end (learn on the train map, reuse on the test map, report)."""

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from tensordict import TensorDict
from torchrl.envs.utils import check_env_specs

from drs_torchrl.data import StageBuffers
from drs_torchrl.envs.maze import (
    BOTTOM_ROOM,
    convert_observation,
    decode_cells,
    GATES,
    MOVES,
    OBS_DIMS,
    SIZE,
    TOP_ROOM,
    WALL_ROWS,
    ThreeRoomMaze,
    make_grid,
    observation,
)
from drs_torchrl.objectives import DiscriminatorLoss
from drs_torchrl.apps.maze import MazeConfigError, train, validate
from drs_torchrl.tasks.maze import demo_episodes, make_env, reward_transform
from drs_torchrl.tools.maze_analysis import (
    all_state_actions,
    dense_reward_table,
    report,
    reward_diagnostics,
    reward_label,
)
from drs_torchrl.transforms import DrSReward, StateActionReward, load_reward

ROOT = Path(__file__).resolve().parents[1]
UP, DOWN, LEFT, RIGHT, STAY = range(5)


@pytest.fixture(autouse=True)
def one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def onehot(actions, n=5):
    return torch.nn.functional.one_hot(torch.as_tensor(actions), n).to(torch.bool)


@pytest.mark.parametrize("coords", sorted(OBS_DIMS))
@pytest.mark.parametrize("map_name", sorted(GATES))
def test_specs_pass_torchrl_checks_with_the_stage_label(map_name, coords):
    env = ThreeRoomMaze(map_name, num_envs=4, max_steps=10, seed=0, coords=coords)
    check_env_specs(env)
    labelled = make_env(map_name, 4, 10, 0, "drs", coords)
    check_env_specs(labelled)
    assert labelled.observation_spec["observation"].shape == (4, OBS_DIMS[coords])
    assert labelled.observation_spec["stage"].shape == (4, 1)
    assert env.action_spec.shape == (4, 5)


def test_train_and_test_maps_differ_only_in_the_two_gates():
    train, test = make_grid("train"), make_grid("test")
    assert train.shape == test.shape == (SIZE, SIZE)
    diff = (train != test).nonzero().tolist()
    for name, grid in (("train", train), ("test", test)):
        for row, gate in zip(WALL_ROWS, GATES[name]):
            assert (~grid[row]).nonzero().reshape(-1).tolist() == [gate]  # one gate per inner wall
    assert GATES["train"][0] != GATES["test"][0] and GATES["train"][1] != GATES["test"][1]
    expected = sorted([[r, c] for r, g1, g2 in zip(WALL_ROWS, GATES["train"], GATES["test"]) for c in (g1, g2)])
    assert sorted(diff) == expected


def test_dynamics_walls_success_truncation_and_partial_reset():
    env = ThreeRoomMaze("train", num_envs=3, max_steps=4, seed=3)
    td = env.reset()
    rows = env.pos[:, 0]
    assert ((rows >= BOTTOM_ROOM[0]) & (rows <= BOTTOM_ROOM[1])).all()
    assert ((env.goal[:, 0] >= TOP_ROOM[0]) & (env.goal[:, 0] <= TOP_ROOM[1])).all()
    # env 0 under the lower wall away from the gate, env 1 right below the goal, env 2 anywhere
    env.pos[0] = torch.tensor([12, 5])
    env.goal[1] = torch.tensor([2, 8])
    env.pos[1] = torch.tensor([3, 8])
    td["action"] = onehot([UP, UP, STAY])
    out = env.step(td)["next"]
    assert env.pos[0].tolist() == [12, 5]  # bumped into the wall: stays
    assert out["success"].reshape(-1).tolist() == [False, True, False]
    assert out["terminated"].reshape(-1).tolist() == [False, True, False]
    assert out["reward"].reshape(-1).tolist() == [0.0, 1.0, 0.0]
    # observation: agent (x=col, y=16-row) and the wall above in the patch
    obs = out["observation"][0]
    assert obs[:SIZE].argmax() == 5 and obs[SIZE : 2 * SIZE].argmax() == SIZE - 1 - 12
    assert obs[-9:].reshape(3, 3)[0].tolist() == [1.0, 1.0, 1.0] and obs[-9:][4] == 0
    # partial reset: only env 1 restarts; the others keep their state and step counter
    pos0 = env.pos[0].clone()
    env.reset(TensorDict({"_reset": torch.tensor([[False], [True], [False]])}, batch_size=[3]))
    assert env.pos[0].tolist() == pos0.tolist() and env.t.tolist() == [1, 0, 1]
    for _ in range(3):
        out = env.step(TensorDict({"action": onehot([STAY, STAY, STAY])}, batch_size=[3]))["next"]
    assert out["truncated"].reshape(-1).tolist() == [True, False, True]
    assert not out["terminated"].any()


def test_demonstrations_are_shortest_paths_that_end_in_success():
    env = ThreeRoomMaze("train", num_envs=1)
    dist = env.shortest_distances()
    for ep in demo_episodes("train", 5, seed=1, coords="scalar"):
        nxt = ep["next"]
        assert nxt["stage"][-1].item() == 1 and nxt["stage"][:-1].sum() == 0
        first = nxt["observation"][0]
        col, row = round(float(first[0]) * 16), 16 - round(float(first[1]) * 16)
        gcol, grow = round(float(first[2]) * 16), 16 - round(float(first[3]) * 16)
        gi = [tuple(g) for g in env.goal_cells.tolist()].index((grow, gcol))
        assert len(nxt["stage"]) == dist[gi, row, col]  # as many steps as the shortest path


def test_state_action_reward_reads_s_and_a_at_the_root_and_the_stage_of_s_prime():
    torch.manual_seed(0)
    obs_dim = OBS_DIMS["onehot"]
    r = DrSReward(1, ["observation", "action"], {"observation": obs_dim, "action": 5}, formula="rescaled")
    r.discriminators.trained[:] = True
    B = 6
    td = TensorDict(
        {
            "observation": torch.rand(B, obs_dim),
            "action": onehot([0, 1, 2, 3, 4, 0]),
            "next": {
                "observation": torch.rand(B, obs_dim),
                "stage": torch.tensor([[0]] * 5 + [[1]]),
                "reward": torch.zeros(B, 1),
            },
        },
        batch_size=[B],
    )
    StateActionReward(r)(td)
    x = torch.cat([td["observation"], td["action"].float()], -1)
    expected = r.alpha * torch.tanh(r.discriminators(x)) - 2.0
    assert torch.allclose(td["next", "reward"][:5], expected[:5])
    assert td["next", "reward"][5].item() == -1.0  # success: (1 + 0) / 1 - 2, no dense term
    # dqn.reward_scale: the agent's reward is multiplied, the discriminator is the same
    scaled = StateActionReward(r, scale=0.1)(td.clone())
    assert torch.allclose(scaled["next", "reward"], 0.1 * td["next", "reward"])


@pytest.mark.parametrize("reward_name", ["semi_sparse", "dense"])
def test_reward_scale_multiplies_the_env_reward(reward_name):
    from torchrl.envs.utils import step_mdp

    envs = [make_env("train", 4, 30, 0, reward_name, reward_scale=s) for s in (1.0, 0.1)]
    actions = onehot(torch.randint(0, 5, (4, 30), generator=torch.Generator().manual_seed(1)))
    rewards = []
    for e in envs:
        check_env_specs(e)
        e.set_seed(3)
        td = e.reset()
        rs = []
        for t in range(30):
            td = e.step(td.set("action", actions[:, t]))
            rs.append(td["next", "reward"])
            td = step_mdp(td)
        rewards.append(torch.stack(rs))
    assert (rewards[0] < 0).all()  # both rewards cost something on every step that does not succeed
    assert torch.allclose(rewards[1], 0.1 * rewards[0])


def test_discriminator_on_maze_state_actions_prefers_the_demonstrated_moves():
    """Algorithm 1's reward step alone on (s, a): positives from shortest-path demonstrations,
    negatives from random-walk failures, then argmax_a R(s, a) agrees with shortest paths far
    more often than chance (about 1/3 of actions are optimal in a cell)."""
    torch.manual_seed(0)
    reward = DrSReward(
        1, ["observation", "action"], {"observation": OBS_DIMS["onehot"], "action": 5}, formula="rescaled"
    )
    buffers = StageBuffers(1, ["observation", "action"], capacity=20000, batch_size=256)
    for ep in demo_episodes("train", 60, seed=0):
        buffers.add_trajectory(ep, demo=True)
    env = make_env("train", 64, 60, 0, "drs")
    fail = env.rollout(60)  # random actions: no success within 60 steps from the bottom room
    assert not fail["next", "success"].any()
    flat = fail.reshape(-1)
    buffers.add_trajectory(
        TensorDict(
            {
                "next": {
                    "observation": flat["observation"],
                    "action": flat["action"].float(),
                    "stage": flat["next", "stage"],
                }
            },
            batch_size=flat.batch_size,
        )
    )
    loss = DiscriminatorLoss(reward.discriminators, ["observation", "action"], early_stop_threshold=None)
    opt = torch.optim.Adam(reward.discriminators.parameters(), lr=3e-3)
    for _ in range(300):
        out = loss(buffers.sample_discriminator_batch())
        opt.zero_grad()
        out["loss_discriminator"].backward()
        opt.step()
    assert out["accuracy_0"] > 0.8
    # in the bottom room (where both sides have data), argmax_a R(s, a) is a shortest-path move far
    # more often than a random move is
    env = ThreeRoomMaze("train", num_envs=1)
    dist = env.shortest_distances()
    hits, chance, n = 0.0, 0.0, 0
    for gi in range(0, len(env.goal_cells), 7):
        cells, r = dense_reward_table(reward, "train", tuple(env.goal_cells[gi].tolist()))
        bottom = cells[:, 0] >= BOTTOM_ROOM[0]
        cells, r = cells[bottom], r[bottom]
        nxt = cells.unsqueeze(1) + MOVES  # (n, 5, 2)
        nxt = torch.where(env.grid[nxt[..., 0], nxt[..., 1]].unsqueeze(-1), cells.unsqueeze(1), nxt)
        good = dist[gi][nxt[..., 0], nxt[..., 1]] == dist[gi][cells[:, 0], cells[:, 1]].unsqueeze(1) - 1
        hits += float(good.gather(1, r.argmax(-1, keepdim=True)).float().sum())
        chance += float(good.float().mean(-1).sum())
        n += len(cells)
    assert hits / n > chance / n + 0.3, (hits / n, chance / n)
    diag = reward_diagnostics(reward, "train", 60)
    assert set(diag) == {"optimal_action_rate", "always_up_rate", "greedy_success"}
    # a reward without preferences (every action equal) picks "up" everywhere: exactly the reference rate
    flat = DrSReward(1, ["observation", "action"], {"observation": OBS_DIMS["onehot"], "action": 5}, formula="rescaled")
    flat_diag = reward_diagnostics(flat, "train", 60)  # untrained discriminators score 0 for every (s, a)
    assert flat_diag["optimal_action_rate"] == flat_diag["always_up_rate"] == diag["always_up_rate"] > 0.5


@pytest.mark.parametrize("name", ["drs", "vice_raq", "oril", "gail"])
def test_every_maze_reward_learner_takes_a_fractional_step_rate(name):
    """``dqn.reward_updates_per_update=0.5`` (the schema allows fractions): one learner step every second DQN update,
    for DrS and for the classifier baselines alike (the baselines' rate was once cut to an int: 0.5 became 0)."""
    from drs_torchrl.apps.maze import make_reward

    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base=None):
        cfg = compose("maze", overrides=[f"reward.name={name}", "dqn.reward_updates_per_update=0.5", "demos=2"])
    learner, _ = make_reward(cfg, "train", learn=True)
    assert learner.reward_updates_per_update == 0.5
    assert [learner._steps_due() for _ in range(4)] == [0, 1, 0, 1]


def test_config_errors_name_the_fix():
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base=None):
        with pytest.raises(MazeConfigError, match="reward.checkpoint"):
            validate(compose("maze", overrides=["phase=reuse", "reward.name=drs"]))
        with pytest.raises(MazeConfigError, match=r"phase=learn learns one of .*run with phase=reuse"):
            validate(compose("maze", overrides=["phase=learn", "reward.name=sparse"]))
        with pytest.raises(MazeConfigError, match="demos > 0"):
            validate(compose("maze", overrides=["phase=learn", "reward.name=gail", "demos=0"]))
        with pytest.raises(MazeConfigError, match="reward.name=gail"):  # gail_stages reuses a GAIL checkpoint
            validate(compose("maze", overrides=["phase=reuse", "reward.name=gail_stages"]))
        with pytest.raises(MazeConfigError, match="dqn.reward_scale must be > 0"):
            validate(compose("maze", overrides=["dqn.reward_scale=0"]))
        with pytest.raises(MazeConfigError, match="multiple of num_envs"):
            validate(compose("maze", overrides=["num_envs=7"]))
        with pytest.raises(MazeConfigError, match="use reward.coords=relative, patch or null"):
            validate(compose("maze", overrides=["coords=relative", "reward.coords=onehot"]))
        validate(compose("maze", overrides=["coords=onehot", "reward.coords=relative"]))  # re-encodable: fine
        with pytest.raises(MazeConfigError, match="reward.name=sparse is a static reward and reads no checkpoint"):
            validate(compose("maze", overrides=["phase=reuse", "reward.name=sparse", "reward.checkpoint=r.pt"]))


TINY = [
    "num_envs=8",
    "max_steps=40",
    "total_frames=1024",
    "dqn.frames_per_batch=128",
    "dqn.learning_starts=256",
    "dqn.batch_size=32",
    "dqn.utd=0.25",
    "eval.interval=512",
    "eval.episodes=8",
    "verbose=false",
    "reward.stage_buffer_size=4000",
    "reward.disc.batch_size=32",
]


@pytest.mark.sim
@pytest.mark.slow
def test_drs_maze_learn_then_reuse_then_report(tmp_path):
    learn_dir = tmp_path / "study" / "learn-s0"
    env = {**os.environ, "HYDRA_FULL_ERROR": "1"}
    exe = Path(sys.executable).parent / "drs-maze"
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "drs_torchrl.apps.maze"]
    proc = subprocess.run(
        [*cmd, "phase=learn", "demos=10", f"hydra.run.dir={learn_dir}", *TINY],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "reward checkpoint" in proc.stdout
    for f in ("config.yaml", "train.csv", "summary.json", "reward.pt", "policy.pt", "reward_map.png"):
        assert (learn_dir / f).is_file(), f
    assert (learn_dir / "reward_map.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rows = list(csv.DictReader((learn_dir / "train.csv").read_text().splitlines()))
    assert [int(r["frames"]) for r in rows] == [0, 512, 1024]
    assert {"eval_success", "train_success", "disc_loss", "success_buffer"} <= set(rows[0])
    summ = json.loads((learn_dir / "summary.json").read_text())
    assert summ["map"] == "train" and summ["frames"] == 1024 and summ["disc_updates"] > 0
    assert summ["stage_buffer_counts"][1] >= 10  # the demonstrations sit in the success buffer
    reward = DrSReward.from_checkpoint(learn_dir / "reward.pt")
    assert reward.reward_in_keys == ["observation", "action"] and reward.metadata["map"] == "train"
    assert reward.discriminators.trained.all()

    # phase 2 and the baseline through the same function the CLI calls
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base=None):
        for name, extra in (("drs", [f"reward.checkpoint={learn_dir / 'reward.pt'}"]), ("sparse", [])):
            cfg = compose("maze", overrides=["phase=reuse", f"reward.name={name}", *extra, *TINY])
            s = train(cfg, tmp_path / "study" / f"reuse-{name}-s0")
            assert s["map"] == "test" and s["reward"] == name and s["frames"] == 1024
        # an agent seeing only relative coordinates cannot feed a reward learned on absolute ones
        with pytest.raises(MazeConfigError, match="coords=onehot"):
            cfg = compose(
                "maze",
                overrides=["phase=reuse", "coords=relative", f"reward.checkpoint={learn_dir / 'reward.pt'}", *TINY],
            )
            train(cfg, tmp_path / "bad")
        assert not (tmp_path / "bad").exists()  # nothing written for a run that cannot start
    assert (tmp_path / "study" / "reuse-drs-s0" / "reward_map.png").is_file()
    assert not (tmp_path / "study" / "reuse-sparse-s0" / "reward.pt").exists()
    # the frozen reward is the learned one: same values on every (s, a) of the test map
    _, feats = all_state_actions("test", (2, 8))
    frozen = DrSReward.from_checkpoint(learn_dir / "reward.pt")
    assert torch.equal(frozen.discriminators(feats), reward.discriminators(feats))

    out = report(tmp_path / "study", tmp_path / "results")
    assert out["runs"] == 3
    assert (tmp_path / "results" / "curves.png").read_bytes()[:4] == b"\x89PNG"
    curves = list(csv.DictReader((tmp_path / "results" / "curves.csv").read_text().splitlines()))
    assert {(r["phase"], r["reward"]) for r in curves} == {("learn", "drs"), ("reuse", "drs"), ("reuse", "sparse")}
    table = (tmp_path / "results" / "table.md").read_text()
    assert "| reuse | test | sparse |" in table and "| learn | train | drs |" in table

    # a scaled reward is its own group, and a report can gather several folders
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base=None):
        s = train(
            compose("maze", overrides=["phase=reuse", "reward.name=sparse", "dqn.reward_scale=0.5", *TINY]),
            tmp_path / "study2" / "reuse-sparse-s0",
        )
    assert s["reward_scale"] == 0.5
    out = report([tmp_path / "study", tmp_path / "study2"], tmp_path / "results2")
    assert out["runs"] == 4
    curves = list(csv.DictReader((tmp_path / "results2" / "curves.csv").read_text().splitlines()))
    assert {r["reward"] for r in curves if r["phase"] == "reuse"} == {"drs", "sparse", "sparse x0.5"}
    assert reward_label({"reward": "drs", "reward_coords": "patch", "reward_scale": 0.1}) == "drs[patch] x0.1"
    with pytest.raises(MazeConfigError, match="no runs"):
        report(tmp_path / "nothing-here", tmp_path / "results3")


def test_observation_matches_the_grid_for_every_cell():
    grid = make_grid("test")
    cells = (~grid).nonzero()
    obs = observation(grid, cells, torch.tensor([2, 8]).expand(len(cells), 2), "onehot")
    patch = obs[:, -9:].reshape(-1, 3, 3)
    for (r, c), p in zip(cells.tolist(), patch):
        assert p.bool().tolist() == grid[r - 1 : r + 2, c - 1 : c + 2].tolist()
    # moves: the stay action keeps the cell, the others change it by one
    assert MOVES.abs().sum(-1).tolist() == [1, 1, 1, 1, 0]


def test_dense_baseline_reward_is_a_cost_shrinking_along_the_shortest_path():
    env = ThreeRoomMaze("test", num_envs=2, max_steps=50, seed=0, dense_coef=1.0)
    sparse = ThreeRoomMaze("test", num_envs=2, max_steps=50, seed=0)
    td = env.reset()
    dmax = float(env.shortest_distances().max())
    goal = (2, 8)  # a top-room cell away from the walls
    env.goal[:] = torch.tensor(goal)
    # env 0 one step left of the goal, env 1 one step right of it: both moves reach the goal
    env.pos[0] = torch.tensor([goal[0], goal[1] - 1])
    env.pos[1] = torch.tensor([goal[0] + 1, goal[1]])
    td["action"] = onehot([RIGHT, UP])
    out = env.step(td)["next"]
    assert out["success"].all() and torch.allclose(out["reward"], torch.ones(2, 1))  # d = 0 at the goal
    # away from the goal: the cost is d(s') / d_max, and a step closer always earns more than a step away
    rewards = {}
    for a, d_next in ((UP, 1), (STAY, 2), (LEFT, 3)):
        env.reset()
        env.goal[:] = torch.tensor(goal)
        env.pos[:] = torch.tensor([goal[0] + 2, goal[1]])  # two rows below the goal, same room
        out = env.step(TensorDict({"action": onehot([a, a])}, batch_size=[2]))["next"]
        assert torch.allclose(out["reward"], torch.full((2, 1), -d_next / dmax))
        rewards[a] = float(out["reward"][0])
    assert rewards[UP] > rewards[STAY] > rewards[LEFT]
    # the sparse env (dense_coef=0) is unchanged: 0 a step
    sparse.reset()
    out = sparse.step(TensorDict({"action": onehot([STAY, STAY])}, batch_size=[2]))["next"]
    assert (out["reward"] == 0).all()


def test_relative_reward_view_is_decoded_from_the_agents_observation():
    grid = make_grid("test")
    cells = torch.tensor([[13, 4], [2, 8], [7, 15], [14, 1]])
    goals = torch.tensor([[2, 8], [3, 9], [1, 1], [4, 15]])
    for src in ("onehot", "scalar"):
        obs = observation(grid, cells, goals, src)
        pos, goal = decode_cells(obs, src)
        assert torch.equal(pos, cells) and torch.equal(goal, goals)
        rel = convert_observation(obs, src, "relative")
        assert torch.equal(rel, observation(grid, cells, goals, "relative"))
        # goal offset (dx = columns, dy = rows upwards) / 16, then the same 3x3 patch
        assert torch.allclose(rel[0, :2], torch.tensor([4 / 16, 11 / 16])) and torch.equal(rel[:, 2:], obs[:, -9:])
    with pytest.raises(ValueError, match="absolute"):
        decode_cells(observation(grid, cells, goals, "relative"), "relative")
    # the patch view keeps only the 3x3 neighbourhood, from any view
    for src in ("onehot", "scalar", "relative"):
        obs = observation(grid, cells, goals, src)
        assert torch.equal(convert_observation(obs, src, "patch"), observation(grid, cells, goals, "patch"))
    assert observation(grid, cells, goals, "patch").shape == (4, OBS_DIMS["patch"])
    assert observation(grid, cells, goals, "patch")[2].tolist() == [
        0,
        0,
        1,
        0,
        0,
        1,
        0,
        0,
        1,
    ]  # (7, 15): wall on the right
    # a reward learned on the relative view reads an agent's one-hot transitions through StateActionReward
    drs = DrSReward(1, ["observation", "action"], {"observation": OBS_DIMS["relative"], "action": 5})
    obs = observation(grid, cells, goals, "onehot")
    act = torch.nn.functional.one_hot(torch.tensor([UP, DOWN, LEFT, STAY]), 5).float()
    td = TensorDict({"observation": obs, "action": act, "next": {"stage": torch.zeros(4, 1, dtype=torch.long)}}, [4])
    got = reward_transform(drs, "onehot")(td)["next", "reward"]
    want = drs.reward(
        TensorDict(
            {
                "observation": observation(grid, cells, goals, "relative"),
                "action": act,
                "stage": torch.zeros(4, 1, dtype=torch.long),
            },
            [4],
        )
    )
    assert torch.allclose(got, want)


@pytest.mark.sim
@pytest.mark.slow
def test_a_patch_only_reward_learns_and_is_reused(tmp_path):
    """``reward.coords=patch``: the reward reads the 3x3 patch and the action, no coordinates."""
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base=None):
        s = train(
            compose("maze", overrides=["phase=learn", "demos=10", "reward.coords=patch", *TINY]), tmp_path / "learn"
        )
        assert s["disc_updates"] > 0
        reward = DrSReward.from_checkpoint(tmp_path / "learn" / "reward.pt")
        assert reward.in_shapes["observation"] == OBS_DIMS["patch"]
        s = train(
            compose("maze", overrides=["phase=reuse", f"reward.checkpoint={tmp_path / 'learn' / 'reward.pt'}", *TINY]),
            tmp_path / "reuse",
        )
        assert s["map"] == "test" and s["frames"] == 1024 and s["reward_coords"] == "patch"
    # same patch and action, anywhere on either map: the same reward
    grid = make_grid("train")
    cells, goals = torch.tensor([[13, 5], [8, 9]]), torch.tensor([[2, 8], [3, 1]])  # both open all round
    act = torch.nn.functional.one_hot(torch.tensor([UP, UP]), 5).float()
    td = TensorDict(
        {
            "observation": observation(grid, cells, goals, "onehot"),
            "action": act,
            "next": {"stage": torch.zeros(2, 1, dtype=torch.long)},
        },
        [2],
    )
    r = reward_transform(reward, "onehot")(td)["next", "reward"]
    assert torch.equal(r[0], r[1])


def test_n_step_windows_that_reach_the_goal_are_terminal():
    """A 3-step window that ends on the goal must not bootstrap (TorchRL's MultiStepTransform keeps the
    first step's done flags; ``mark_terminal_obs`` / ``terminal_at_window_end`` carry the right one)."""
    from torchrl.data import LazyTensorStorage, ReplayBuffer
    from torchrl.envs.transforms import MultiStepTransform

    from drs_torchrl.updaters.dqn import mark_terminal_obs, terminal_at_window_end

    T = 10
    term = torch.zeros(1, T, 1, dtype=torch.bool)
    term[0, 5] = True  # the goal is reached by the step at t = 5; a new episode starts at t = 6
    trunc = torch.zeros(1, T, 1, dtype=torch.bool)
    trunc[0, 9] = True
    obs = torch.arange(T, dtype=torch.float32).reshape(1, T, 1)
    batch = TensorDict(
        {
            "observation": obs,
            "action": torch.zeros(1, T, 5),
            "next": {
                "observation": obs + 100,
                "reward": torch.ones(1, T, 1),
                "terminated": term,
                "truncated": trunc,
                "done": term | trunc,
            },
        },
        [1, T],
        names=[None, "time"],
    )
    rb = ReplayBuffer(storage=LazyTensorStorage(100, ndim=2), transform=MultiStepTransform(3, 0.9))
    rb.extend(mark_terminal_obs(batch))
    data = terminal_at_window_end(rb.storage[:].reshape(-1).clone())
    by_t = {
        int(o): (bool(t), float(n), int(k))
        for o, t, n, k in zip(
            data["observation"].reshape(-1),
            data["next", "terminated"].reshape(-1),
            data["next", "observation"].reshape(-1),
            data["steps_to_next_obs"].reshape(-1),
        )
    }
    # windows from t = 3, 4, 5 end on the goal (obs 105): terminal; t = 2 ends on 104: not
    assert by_t[3] == (True, 105.0, 3) and by_t[4] == (True, 105.0, 2) and by_t[5] == (True, 105.0, 1)
    assert by_t[2] == (False, 104.0, 3) and by_t[6] == (False, 108.0, 3)


def test_the_dqn_agents_state_round_trips_with_its_target_schedule():
    """DQNUpdater.state_dict carries the target network's copy counter with the rest, so an agent loaded from it copies
    its target at the same update as the one saved."""
    from drs_torchrl.apps.maze import make_updater
    from drs_torchrl.config_dir import conf_dir

    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        cfg = compose("maze", overrides=["phase=reuse", "reward.name=sparse", "dqn.n_steps=1"])
    env = make_env("test", 2, 10, 0, "sparse")
    saved, fresh = make_updater(cfg, env, None, False), make_updater(cfg, env, None, False)
    for _ in range(3):
        saved.target_updater.step()
    fresh.load_state_dict(saved.state_dict())
    assert saved.target_updater.state_dict()["counter"] == 3
    assert fresh.target_updater.state_dict() == saved.target_updater.state_dict()


def test_the_maze_agents_are_built_from_their_config_and_every_setting_reaches_them():
    """``dqn.updater`` / ``ppo.updater`` (conf/maze.yaml) are built by ``hydra.utils.instantiate``: an override of any
    ``dqn.*`` / ``ppo.*`` setting must reach the TorchRL object it configures."""
    from drs_torchrl.apps.maze import make_updater
    from drs_torchrl.config_dir import conf_dir

    dqn = ["dqn.lr=0.002", "dqn.gamma=0.9", "dqn.double_dqn=false", "dqn.loss_function=l2", "dqn.eps_init=0.5",
           "dqn.eps_end=0.2", "dqn.eps_anneal_frac=0.25", "total_frames=1000", "dqn.utd=0.5", "dqn.learning_starts=7",
           "dqn.grad_clip=3", "dqn.hidden=[8]", "dqn.target_update.value_network_update_interval=9"]  # fmt: skip
    ppo = ["agent=ppo", "ppo.lr=0.002", "ppo.gamma=0.9", "ppo.lmbda=0.5", "ppo.epochs=3", "ppo.batch_size=32",
           "ppo.clip_epsilon=0.1", "ppo.entropy_coeff=0.05", "ppo.critic_coeff=2.0", "ppo.grad_clip=0.3", "ppo.hidden=[8]"]  # fmt: skip
    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        d = compose("maze", overrides=["phase=reuse", "reward.name=sparse", *dqn])
        p = compose("maze", overrides=["phase=reuse", "reward.name=sparse", *ppo])
    env = make_env("test", 2, 10, 0, "sparse")
    u = make_updater(d, env, None, False)
    assert u.optimizer.defaults["lr"] == 0.002 and u.loss.value_estimator.gamma == pytest.approx(0.9)
    assert u.loss.double_dqn is False and u.loss.loss_function == "l2" and u.grad_clip == 3.0
    assert float(u.explore.eps_init) == 0.5 and float(u.explore.eps_end) == pytest.approx(0.2)
    assert u.explore.annealing_num_steps == 250 and u.budget.per_frame == 0.5 and u.learning_starts == 7
    assert u.target_updater.value_network_update_interval == 9 and u.n_step  # dqn.n_steps=5: windows
    assert [m.out_features for m in u.actor.modules() if isinstance(m, torch.nn.Linear)] == [8, 5]
    v = make_updater(p, env, None, False)
    assert v.optimizer.defaults["lr"] == 0.002 and v.epochs == 3 and v.minibatch_size == 32 and v.max_grad_norm == 0.3
    assert float(v.advantage.gamma) == pytest.approx(0.9) and float(v.advantage.lmbda) == pytest.approx(0.5)
    assert float(v.loss.clip_epsilon) == pytest.approx(0.1, abs=1e-6) and float(v.loss.entropy_coeff) == pytest.approx(
        0.05
    )
    assert float(v.loss.critic_coeff) == 2.0 and v.hidden == [8]


def test_next_state_reward_reads_s_prime_and_a_move_into_a_wall_scores_as_staying():
    """``reward.input=next_state``: R(s') (Sec. 4.3). The reward table of a cell gives a blocked
    move the value of "stay", and the reward transform reads the observation under ``"next"``."""
    torch.manual_seed(0)
    r = DrSReward(
        1,
        ["observation"],
        {"observation": OBS_DIMS["onehot"]},
        formula="rescaled",
        metadata={"family": "three_room_maze", "reward_on": "next_state"},
    )
    r.discriminators.trained[:] = True
    cells, table = dense_reward_table(r, "train", (2, 8))
    corner = [i for i, c in enumerate(cells.tolist()) if c == [15, 1]][0]  # bottom-left corner: down and left are walls
    assert table[corner, DOWN] == table[corner, STAY] == table[corner, LEFT] != table[corner, UP]
    B = 4
    td = TensorDict(
        {
            "observation": torch.rand(B, OBS_DIMS["onehot"]),
            "action": onehot([0, 1, 2, 3]),
            "next": {
                "observation": torch.rand(B, OBS_DIMS["onehot"]),
                "stage": torch.zeros(B, 1, dtype=torch.long),
                "reward": torch.zeros(B, 1),
            },
        },
        batch_size=[B],
    )
    got = StateActionReward(r)(td)["next", "reward"]
    assert torch.allclose(got, r.alpha * torch.tanh(r.discriminators(td["next", "observation"])) - 2.0)
    for ep in demo_episodes("train", 3, seed=0, next_state=True):  # demonstrations carry s', the last one the goal
        goal_obs = ep["next", "observation"][-1]
        assert torch.equal(goal_obs[: 2 * SIZE], goal_obs[2 * SIZE : 4 * SIZE])  # agent on the goal


@pytest.mark.sim
@pytest.mark.slow
def test_control_options_next_state_demos_only_constant_part_and_moved_gate_maps(tmp_path):
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base=None):
        s = train(
            compose(
                "maze", overrides=["phase=learn", "reward.input=next_state", "reward.positives=demos", "demos=5", *TINY]
            ),
            tmp_path / "learn",
        )
        reward = DrSReward.from_checkpoint(tmp_path / "learn" / "reward.pt")
        assert reward.reward_in_keys == ["observation"] and reward.metadata["reward_on"] == "next_state"
        assert s["reward_input"] == "next_state"
        demo_steps = sum(len(ep) for ep in demo_episodes("train", 5, 0, next_state=True))
        assert s["stage_buffer_counts"][1] == demo_steps  # positives=demos: the agent's successes are not filed
        s = train(
            compose(
                "maze",
                overrides=[
                    "phase=reuse",
                    "map=test_shift3",
                    f"reward.checkpoint={tmp_path / 'learn' / 'reward.pt'}",
                    "reward.reuse_alpha=0",
                    *TINY,
                ],
            ),
            tmp_path / "reuse",
        )
        assert s["map"] == "test_shift3" and s["reward_alpha"] == 0.0
        assert reward_label(s) == "drs[s'] constant part (alpha=0)"
        rows = list(csv.DictReader((tmp_path / "reuse" / "train.csv").read_text().splitlines()))
        means = [float(r["reward_mean"]) for r in rows if r["reward_mean"] not in ("", "nan")]
        assert means and all(-2.0 <= m <= -1.0 for m in means)  # alpha=0: -2 a step, -1 on success, nothing learned
        with pytest.raises(MazeConfigError, match="demos > 0"):
            train(
                compose("maze", overrides=["phase=learn", "reward.positives=demos", "demos=0", *TINY]), tmp_path / "bad"
            )
    grid = make_grid("test_shift3")
    assert [(~grid[row]).nonzero().reshape(-1).tolist() for row in WALL_ROWS] == [[6], [10]]


SHORT = [o if not o.startswith("total_frames=") else "total_frames=512" for o in TINY]


@pytest.mark.sim
@pytest.mark.slow
@pytest.mark.parametrize("name", ["vice_raq", "oril", "gail"])
def test_learned_baselines_run_on_the_maze_core_and_are_reused(name, tmp_path):
    """VICE-RAQ, ORIL and GAIL on the maze through the shared learners: phase 1 writes a classifier
    checkpoint of that method, phase 2 reuses it (GAIL also as gail_stages), and a checkpoint of
    another method is refused with the fix named."""
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base=None):
        s = train(
            compose(
                "maze",
                overrides=[
                    "phase=learn",
                    f"reward.name={name}",
                    "demos=5",
                    "reward.classifier.offline_updates=50",
                    "reward.classifier.random_episodes=3",
                    "reward.classifier.batch_size=32",
                    *SHORT,
                ],
            ),
            tmp_path / "learn",
        )
        reward = load_reward(tmp_path / "learn" / "reward.pt")
        assert reward.method == name and reward.use_action == (name == "gail") and s["disc_updates"] > 0
        assert bool(reward.classifier.trained)
        lo, hi = reward.reward_bounds()
        rows = list(csv.DictReader((tmp_path / "learn" / "train.csv").read_text().splitlines()))
        means = [float(r["reward_mean"]) for r in rows if r["reward_mean"] not in ("", "nan")]
        assert means and all(lo - 1e-6 <= m <= hi + 1e-6 for m in means) and hi <= 0.0  # every step costs
        assert (tmp_path / "learn" / "reward_map.png").is_file() and "reward_diagnostics" in s
        reuse_as = ["gail", "gail_stages"] if name == "gail" else [name]
        for as_name in reuse_as:
            r2 = train(
                compose(
                    "maze",
                    overrides=[
                        "phase=reuse",
                        f"reward.name={as_name}",
                        f"reward.checkpoint={tmp_path / 'learn' / 'reward.pt'}",
                        "dqn.reward_scale=0.1",
                        *SHORT,
                    ],
                ),
                tmp_path / f"reuse-{as_name}",
            )
            assert r2["map"] == "test" and r2["reward"] == as_name
        other = "vice_raq" if name != "vice_raq" else "oril"
        with pytest.raises(MazeConfigError, match="must match"):
            train(
                compose(
                    "maze",
                    overrides=[
                        "phase=reuse",
                        f"reward.name={other}",
                        f"reward.checkpoint={tmp_path / 'learn' / 'reward.pt'}",
                        *SHORT,
                    ],
                ),
                tmp_path / "bad",
            )
    if name == "gail":  # the stage term: a success step earns w_s * 0, every other step w_s * (0 - 1) more than D alone
        frozen = load_reward(tmp_path / "learn" / "reward.pt")
        td = TensorDict(
            {
                "observation": torch.zeros(2, OBS_DIMS["onehot"]),
                "action": onehot([0, 1]).float(),
                "next": {"observation": torch.zeros(2, OBS_DIMS["onehot"]), "stage": torch.tensor([[0], [1]])},
            },
            batch_size=[2],
        )
        plain = frozen.reward(td)
        frozen.stage_weight = 1.0
        staged = frozen.reward(td)
        assert torch.allclose(staged - plain, torch.tensor([[-1.0], [0.0]]))


@pytest.mark.sim
@pytest.mark.slow
@pytest.mark.parametrize("name", ["drs", "gail"])
def test_a_stopped_maze_run_saves_its_state_and_resume_finishes_it(tmp_path, name):
    """SIGTERM: the training state (agent, replay buffer, the learner and its buffers: GAIL's agent transitions too);
    a new run there is refused naming resume=; a resume takes only its RESUME_SETTINGS; it finishes the run, its
    train.csv continuing the interrupted one's, and then keeps no state."""
    run = tmp_path / "run"
    exe = Path(sys.executable).parent / "drs-maze"
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "drs_torchrl.apps.maze"]
    args = [f"reward.name={name}", "demos=10", *(o for o in TINY if not o.startswith("total_frames="))]
    proc = subprocess.Popen(
        [*cmd, *args, "total_frames=10000000", f"hydra.run.dir={run}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.time() + 150
    while time.time() < deadline and proc.poll() is None:
        if (run / "train.csv").is_file() and len((run / "train.csv").read_text().splitlines()) >= 3:
            break  # evaluated at 0 and 512: the learner and the replay buffer hold data
        time.sleep(0.3)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err[-3000:]
    assert f"continue with drs-maze resume={run}" in err
    stopped_at = int((run / "checkpoints" / "state" / "COMPLETE").read_text())
    assert stopped_at >= 512 and not (run / "summary.json").exists()
    state = sorted(p.name for p in (run / "checkpoints" / "state").iterdir())
    assert "replay" in state and ("stage_buffers" in state if name == "drs" else "agent_transitions" in state)
    before = (run / "train.csv").read_text()
    for extra, expect in [
        ([f"hydra.run.dir={run}"], f"continue it with drs-maze resume={run}"),  # a new run over it
        ([f"resume={run}", "dqn.lr=0.1"], "cannot change dqn.lr of a maze run being resumed"),
    ]:
        p = subprocess.run([*cmd, *extra], capture_output=True, text=True, timeout=120, check=False)
        assert p.returncode == 2 and expect in p.stderr, (extra, p.stderr[-2000:])
        assert (run / "train.csv").read_text() == before
    p = subprocess.run(
        [*cmd, f"resume={run}", f"total_frames={stopped_at + 512}"], capture_output=True, text=True, timeout=300
    )
    assert p.returncode == 0, p.stderr[-3000:]
    s = json.loads((run / "summary.json").read_text())
    assert s["resumed_from"] == stopped_at and s["frames"] >= stopped_at + 512 and s["disc_updates"] > 0
    frames = [int(r["frames"]) for r in csv.DictReader((run / "train.csv").read_text().splitlines())]
    assert frames[0] == 0 and frames == sorted(set(frames)) and frames[-1] == s["frames"]
    assert not (run / "checkpoints").exists() and (run / "reward.pt").is_file()
    p = subprocess.run([*cmd, f"resume={run}"], capture_output=True, text=True, timeout=120, check=False)
    assert p.returncode == 2 and "finished (summary.json)" in p.stderr


@pytest.mark.sim
def test_an_existing_run_directory_is_refused_unless_overwrite(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "summary.json").write_text('{"old": true}')
    (run / "train.csv").write_text("frames\n0\n")
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base=None):
        with pytest.raises(MazeConfigError, match=r"already holds a run \(summary.json, train.csv\).*overwrite=true"):
            train(compose("maze", overrides=["phase=reuse", "reward.name=sparse", *TINY]), run)
        assert (run / "summary.json").read_text() == '{"old": true}'  # nothing touched
        s = train(compose("maze", overrides=["phase=reuse", "reward.name=sparse", "overwrite=true", *TINY]), run)
    assert s["frames"] == 1024 and "old" not in json.loads((run / "summary.json").read_text())
    assert [int(r["frames"]) for r in csv.DictReader((run / "train.csv").read_text().splitlines())] == [0, 512, 1024]


@pytest.mark.sim
@pytest.mark.slow
def test_a_refused_drs_maze_keeps_the_runs_hydra_record_and_a_replacing_one_takes_its_place(tmp_path):
    """Hydra writes .hydra before drs-maze starts: a run refused in a directory holding a run had overwritten that
    run's record, and one refused in a new directory left a folder holding only .hydra."""
    exe = Path(sys.executable).parent / "drs-maze"
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "drs_torchrl.apps.maze"]

    def maze(*args):
        return subprocess.run([*cmd, *args], capture_output=True, text=True, timeout=120, check=False)

    run = tmp_path / "run"
    (run / ".hydra").mkdir(parents=True)
    (run / ".hydra" / "config.yaml").write_text("the earlier run's record\n")
    (run / "summary.json").write_text('{"old": true}')
    p = maze("phase=reuse", "reward.name=sparse", f"hydra.run.dir={run}", *TINY)
    assert p.returncode == 2 and "already holds a run" in p.stderr
    assert sorted(f.name for f in run.iterdir()) == [".hydra", "summary.json"]
    assert (run / ".hydra" / "config.yaml").read_text() == "the earlier run's record\n"
    p = maze("total_frames=-1", f"hydra.run.dir={tmp_path / 'new'}")
    assert p.returncode == 2 and "total_frames must be > 0" in p.stderr and not (tmp_path / "new").exists()
    p = maze("phase=reuse", "reward.name=sparse", "overwrite=true", f"hydra.run.dir={run}", *TINY)
    assert p.returncode == 0, p.stderr[-2000:]
    assert "\nphase: reuse\n" in (run / ".hydra" / "config.yaml").read_text()  # the new run's record, in place
    assert not list(run.glob(".hydra-*")) and "old" not in (run / "summary.json").read_text()
    busy = tmp_path / "busy"  # a directory another process writes: no record of this refused run is left in it
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            f"import time; from drs_torchrl.runtime.rundir import lock_run_dir; lock_run_dir({str(busy)!r}); "
            "print('locked', flush=True); time.sleep(120)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        p = maze("phase=reuse", "reward.name=sparse", f"hydra.run.dir={busy}", *TINY)
        assert p.returncode == 2 and "is being written by another process" in p.stderr
        assert [f.name for f in busy.iterdir()] == [".drs-lock"]  # the holder's lock only
    finally:
        holder.kill()


@pytest.mark.sim
@pytest.mark.slow
def test_ppo_learns_the_maze_reward_beside_it_and_reuses_it(tmp_path):
    """The maze on the one loop with another algorithm: PPO (ClipPPOLoss + GAE, a categorical policy) in phase 1
    with the discriminator training beside it, its batches rewarded by the discriminator of the moment, then
    phase 2 with the frozen reward in the env."""
    ppo = ["agent=ppo", "ppo.frames_per_batch=256", "ppo.batch_size=64", "ppo.epochs=2", "ppo.reward_scale=0.1"]
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base=None):
        s = train(compose("maze", overrides=["phase=learn", "demos=10", *ppo, *TINY]), tmp_path / "learn")
        # 4 batches x 2 epochs x 4 minibatches; one discriminator step offered per PPO step
        assert s["algo"] == "ppo" and s["frames"] == 1024 and s["updates"] == 32 and s["disc_updates"] > 0
        rows = list(csv.DictReader((tmp_path / "learn" / "train.csv").read_text().splitlines()))
        assert [int(r["frames"]) for r in rows] == [0, 512, 1024]
        assert {"loss_objective", "loss_critic", "disc_loss", "success_buffer"} <= set(rows[0])
        # the rescaled DrS reward x0.1, from the discriminator: every step costs between 0.1 and ~0.22
        means = [float(r["reward_mean"]) for r in rows if r["reward_mean"] not in ("", "nan")]
        assert means and all(-0.25 <= m <= -0.1 for m in means)
        r = train(
            compose(
                "maze",
                overrides=[
                    "phase=reuse",
                    "reward.name=drs",
                    f"reward.checkpoint={tmp_path / 'learn' / 'reward.pt'}",
                    *ppo,
                    *TINY,
                ],
            ),
            tmp_path / "reuse",
        )
    assert r["algo"] == "ppo" and r["map"] == "test" and r["frames"] == 1024
    assert (tmp_path / "reuse" / "policy.pt").is_file()


@pytest.mark.sim
@pytest.mark.slow
def test_drs_learn_and_drs_reuse_run_the_maze_family(tmp_path, cli):
    """``drs-learn env=maze algo=dqn`` and ``drs-reuse env=maze reward=drs`` are the maze's phases: the same
    runs as ``drs-maze phase=learn|reuse`` (apps/cli.py:maze_arguments)."""
    from drs_torchrl.apps.cli import maze_arguments

    assert maze_arguments(["env=maze", "algo=ppo", "reward=sparse", "seed=3"], "reuse") == [
        "phase=reuse",
        "agent=ppo",
        "reward.name=sparse",
        "seed=3",
    ]
    assert maze_arguments(["env=pick_cube"], "learn") is None
    learn_dir = tmp_path / "learn"
    exe = Path(sys.executable).parent / "drs-learn"
    proc = subprocess.run(
        [str(exe), "env=maze", "algo=dqn", "demos=10", f"hydra.run.dir={learn_dir}", *TINY],
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    summ = json.loads((learn_dir / "summary.json").read_text())
    assert summ["phase"] == "learn" and summ["map"] == "train" and summ["frames"] == 1024
    assert DrSReward.from_checkpoint(learn_dir / "reward.pt").discriminators.trained.all()
    # phase 2 in this process: the frozen reward on the test map
    code, err = cli("reuse", "env=maze", "reward=drs", f"reward.checkpoint={learn_dir / 'reward.pt'}",
                    f"hydra.run.dir={tmp_path / 'reuse'}", *TINY)  # fmt: skip
    assert code == 0, err[-3000:]
    summ = json.loads((tmp_path / "reuse" / "summary.json").read_text())
    assert summ["phase"] == "reuse" and summ["map"] == "test" and summ["reward"] == "drs"
    # what the maze does not take is refused with the reason, nothing written
    for args, expect in [
        (["algo=sac_cpu"], "env=maze runs algo=dqn (the paper's maze agent) or algo=ppo, got algo=sac_cpu"),
        ([f"resume={learn_dir}"], "finished (summary.json) and a finished maze run keeps no training state"),
        (["env.split=test"], "its settings are conf/maze.yaml's"),
    ]:
        code, err = cli("learn", "env=maze", *args, f"hydra.run.dir={tmp_path / 'bad'}")
        assert code == 2 and expect in err, (args, err)
    assert not (tmp_path / "bad").exists()
