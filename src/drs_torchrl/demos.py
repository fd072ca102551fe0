"""Demonstrations for the top stage buffer (Algorithm 1, line 3: ``B_N <- B_N U D``).

DrS optionally seeds the top stage buffer with successful trajectories. The reward reads only next
states, so a demonstration is a sequence of states: actions are not stored and the demonstrator may
use another controller than the RL agent. ``drs-demos`` generates them with ManiSkill's
motion-planning solvers (joint-position control; the state observation is the same under every
controller).

On-disk format (a directory, e.g. ``demos/pick_cube-cube_2cm.demos``):

* ``states/``: a memory-mapped TensorDict (``TensorDict.load_memmap``) of batch ``[S]``, one row per
  state ``s'`` reached by the demonstrator, episodes concatenated in order. Entries:
  ``observation`` (float, the env's flat state), ``stage_indicators`` (float, monotone),
  ``stage`` (int64), every indicator of the family (bool), ``episode`` and ``step`` (int64).
* ``meta.json``: ``format``, ``version``, ``family``, ``env_id``, ``variant``, ``variant_kwargs``,
  ``stage_keys``, ``shapes`` (entry -> trailing size), ``episodes``, ``lengths``, ``seeds``,
  ``solver``.

Episodes are cut at their first successful state (training episodes terminate there).
"""
from __future__ import annotations

import argparse
import importlib
import json
import shutil
import sys
import time
from pathlib import Path

import torch
from tensordict import TensorDict

from drs_torchrl.data.persistence import load_memmap_checked
from drs_torchrl.tasks import TaskFamily, get_family
from drs_torchrl.transforms.stages import StageIndicator

DEMO_FORMAT = "drs-torchrl/demos"
DEMO_VERSION = 1


class DemoError(ValueError):
    """A demonstrations file that cannot be used for this task."""


def _solver(family: TaskFamily):
    ref = family.extra.get("demo_solver")
    if not ref:
        raise DemoError(f"family {family.name!r} has no motion-planning solver; load ManiSkill trajectories or record your own")
    module, _, fn = ref.partition(":")
    return ref, getattr(importlib.import_module(module), fn)


def record_demos(family: TaskFamily, variant: str, num: int, *, seed: int = 0, variant_overrides: dict | None = None,
                 max_tries: int | None = None, progress: bool = True) -> tuple[TensorDict, dict]:
    """Run the family's solver until ``num`` successful episodes are recorded; returns (states, meta)."""
    import gymnasium as gym
    import mani_skill.envs  # noqa: F401

    import drs_torchrl.envs.variants  # noqa: F401
    from drs_torchrl.envs.doctor import ensure_env_ready

    args = family.env_args(variant, variant_overrides)  # train/test: the split's variants, drawn per episode
    env_id, kwargs = args["env_id"], args["env_kwargs"]
    ensure_env_ready(env_id, kwargs)
    ref, solve = _solver(family)
    env = gym.make(env_id, obs_mode="state", control_mode="pd_joint_pos", num_envs=1, sim_backend="physx_cpu",
                   render_mode=None, max_episode_steps=10 * family.max_episode_steps, **kwargs)
    recorder = _Recorder(env, family.all_info_keys, family.task_observation_key)
    labeller = StageIndicator(family.stage_keys)
    episodes, lengths, seeds = [], [], []
    tries, s = 0, seed
    max_tries = max_tries or 3 * num + 10
    t0 = time.time()
    while len(episodes) < num:
        if tries >= max_tries:
            raise RuntimeError(f"the solver succeeded in only {len(episodes)} of {tries} tries on {family.name}/{variant}")
        tries += 1
        try:
            solve(recorder, seed=s)
        except Exception as exc:  # the planner fails on some initial states: try the next seed
            print(f"  seed {s}: solver failed ({exc.__class__.__name__}); skipping", file=sys.stderr)
            s += 1
            continue
        states = recorder.states()
        s += 1
        if states is None:
            continue
        succ = states["success"].reshape(-1).nonzero()
        if succ.numel() == 0:
            continue
        states = labeller(states[: int(succ[0]) + 1])
        n = len(episodes)
        states.set("episode", torch.full((states.shape[0],), n, dtype=torch.long))
        states.set("step", torch.arange(states.shape[0]))
        episodes.append(states)
        lengths.append(states.shape[0])
        seeds.append(s - 1)
        if progress:
            print(f"\r  {len(episodes)}/{num} demos ({time.time() - t0:.0f}s)", end="", file=sys.stderr, flush=True)
    if progress:
        print(file=sys.stderr)
    env.close()
    data = torch.cat(episodes, 0)
    meta = {
        "format": DEMO_FORMAT, "version": DEMO_VERSION, "family": family.name, "env_id": env_id,
        "variant": variant, "variant_kwargs": kwargs, "stage_keys": list(family.stage_keys),
        "shapes": {k: int(data[k].shape[-1]) for k in ("observation", "stage_indicators", family.task_observation_key) if k},
        "episodes": len(episodes), "lengths": lengths, "seeds": seeds, "solver": ref,
    }
    return data, meta


class _Recorder:
    """Wraps the gymnasium env the solver drives and records every state it reaches."""

    def __init__(self, env, info_keys, task_observation_key=None):
        self.env, self.info_keys, self.task_key = env, tuple(info_keys), task_observation_key
        self._rows: list[dict] = []

    def __getattr__(self, name):
        return getattr(self.env, name)

    @property
    def unwrapped(self):
        return self.env.unwrapped

    def reset(self, **kwargs):
        self._rows = []
        return self.env.reset(**kwargs)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        row = {"observation": torch.as_tensor(obs).reshape(-1).float()}
        for k in self.info_keys:
            row[k] = torch.as_tensor(info[k]).reshape(1).bool()
        if self.task_key:  # the robot-agnostic reward input of families such as cross_robot
            row[self.task_key] = self.env.unwrapped.task_observation().reshape(-1).float()
        self._rows.append(row)
        return obs, reward, terminated, truncated, info

    def states(self) -> TensorDict | None:
        if not self._rows:
            return None
        return TensorDict({k: torch.stack([r[k] for r in self._rows]) for k in self._rows[0]}, batch_size=[len(self._rows)])


def save_demos(states: TensorDict, meta: dict, path: str | Path) -> Path:
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    states.memmap(tmp / "states", num_threads=0)
    (tmp / "meta.json").write_text(json.dumps(meta, indent=2))
    if path.exists():
        shutil.rmtree(path)
    tmp.rename(path)
    return path


def load_demos(path: str | Path) -> tuple[list[TensorDict], dict]:
    """Episodes (each a ``(T,)`` TensorDict of states) and the file's metadata."""
    path = Path(path)
    if not (path / "meta.json").is_file():
        raise DemoError(f"{path} is not a drs-torchrl demonstrations directory (no meta.json); make one with drs-demos")
    meta = json.loads((path / "meta.json").read_text())
    if meta.get("format") != DEMO_FORMAT:
        raise DemoError(f"{path}: unknown format {meta.get('format')!r}")
    if int(meta.get("version", 99)) > DEMO_VERSION:
        raise DemoError(f"{path} has demo format version {meta['version']}, newer than this drs-torchrl reads ({DEMO_VERSION})")
    try:
        states = load_memmap_checked(path / "states").clone()
    except Exception as exc:
        raise DemoError(f"{path}: the states cannot be read (corrupt or truncated?): {exc}") from exc
    ep = states["episode"]
    bounds = torch.cat([torch.tensor([0]), (ep[1:] != ep[:-1]).nonzero().reshape(-1) + 1, torch.tensor([ep.numel()])])
    episodes = [states[int(a):int(b)] for a, b in zip(bounds[:-1], bounds[1:])]
    return episodes, meta


def check_demos(meta: dict, family: TaskFamily, in_shapes: dict[str, int], path: str | Path = "") -> None:
    """Raise :class:`DemoError` naming every way the demonstrations do not fit this task."""
    problems = []
    if meta["family"] != family.name:
        problems.append(f"they are from family {meta['family']!r}, the run is family {family.name!r}")
    if list(meta["stage_keys"]) != list(family.stage_keys):
        problems.append(f"their stage indicators are {meta['stage_keys']}, the family's are {list(family.stage_keys)}")
    for k, d in in_shapes.items():
        have = meta["shapes"].get(k)
        if have is None:
            problems.append(f"they lack the reward input {k!r}")
        elif int(have) != int(d):
            problems.append(f"their {k!r} has size {have}, the env's has size {d}")
    if problems:
        raise DemoError(f"demonstrations {path} do not match the task: " + "; ".join(problems))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="drs-demos", description="generate demonstrations with ManiSkill's motion planners")
    p.add_argument("--family", default="pick_cube")
    p.add_argument("--variant", default="train", help="variant name, or train/test (the split's first variant)")
    p.add_argument("--num", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=None, help="default: demos/<family>-<variant>.demos")
    a = p.parse_args(argv)
    if a.num < 1:
        p.error("--num must be >= 1")
    try:
        fam = get_family(a.family)
        out = a.out or Path("demos") / f"{fam.name}-{a.variant}.demos"
        states, meta = record_demos(fam, a.variant, a.num, seed=a.seed)
    except (KeyError, DemoError, RuntimeError) as exc:
        print(f"drs-demos: error: {exc.args[0] if isinstance(exc, KeyError) else exc}", file=sys.stderr)
        return 2
    save_demos(states, meta, out)
    lengths = meta["lengths"]
    print(f"{meta['episodes']} demonstrations ({sum(lengths)} states, length {min(lengths)}-{max(lengths)}) -> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
