"""Demonstrations for the top stage buffer (Algorithm 1, line 3: ``B_N <- B_N U D``).

DrS optionally seeds the top stage buffer with successful trajectories. The reward reads only next
states, so a demonstration is a sequence of states and the demonstrator may use another controller
than the RL agent. Demonstrations recorded from a policy (``--from-policy``) also keep the agent's
actions and the states they were taken in, for rewards of ``(s, a)`` such as GAIL's; planner
demonstrations (joint-position control, not the agent's controller) keep states only. ``drs-demos`` generates them with ManiSkill's
motion-planning solvers (joint-position control; the state observation is the same under every
controller).

On-disk format (a directory, e.g. ``demos/pick_cube-cube_2cm.demos``):

* ``states/``: a memory-mapped TensorDict (``TensorDict.load_memmap``) of batch ``[S]``, one row per
  state ``s'`` reached by the demonstrator, episodes concatenated in order. Entries:
  ``observation`` (float, the env's flat state), ``stage_indicators`` (float, monotone),
  ``stage`` (int64), every indicator of the family (bool), ``episode`` and ``step`` (int64); from a
  policy also ``action`` (the action that led to the row's state) and ``state`` (a sub-TensorDict of
  the reward inputs and ``stage`` of the state it was taken in).
* ``meta.json``: ``format``, ``version``, ``family``, ``env_id``, ``variant``, ``variant_kwargs``,
  ``stage_keys``, ``shapes`` (entry -> trailing size), ``episodes``, ``lengths``, ``seeds``,
  ``solver``; from a policy ``actions`` (``control_mode``, ``size``).

Episodes are cut at their first successful state (training episodes terminate there).

ManiSkill's own trajectory files (``X.h5`` + ``X.json``, e.g. its downloadable datasets) convert to
this format with ``drs-demos --from-h5 X.h5 --family ...`` (:func:`load_maniskill_h5`), which replays
them in the family's env.

The paper's demonstrations come from trained RL agents (Appendix A: "The demonstrations are from a
trained RL agent"). ``drs-demos --from-policy RUN_DIR`` does that for any family, including those
without a solver (``turn_valve``, ``half_cheetah``, the asset-backed ones): it rolls out the run's
SAC policy in the family's env and keeps the episodes that succeed (:func:`record_policy_demos`).
"""

from __future__ import annotations

import argparse
import collections
import importlib
import json
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict

from drs_torchrl.console import UserError, console_script, library_prints
from drs_torchrl.data.persistence import load_memmap_checked
from drs_torchrl.rundir import check_writable, ensure_free, load_run_config, nbytes, space_errors
from drs_torchrl.tasks import TaskFamily, get_family, with_stages, with_task_observation
from drs_torchrl.transforms.stages import StageIndicator, monotone_indicators

DEMO_FORMAT = "drs-torchrl/demos"
DEMO_VERSION = 1


class DemoError(UserError, ValueError):
    """A demonstrations file that cannot be used for this task."""


def _solver(family: TaskFamily):
    ref = family.extra.get("demo_solver")
    if not ref:
        raise DemoError(
            f"family {family.name!r} has no motion-planning solver; load ManiSkill trajectories or record your own"
        )
    module, _, fn = ref.partition(":")
    return ref, getattr(importlib.import_module(module), fn)


def _successful_episode(states: TensorDict, labeller, index: int) -> TensorDict | None:
    """A demonstration's states cut at its first successful state and stage-labelled, with its
    ``episode`` index and ``step`` numbers; ``None`` when it never succeeds."""
    succ = states["success"].reshape(-1).nonzero()
    if succ.numel() == 0:
        return None
    states = labeller(states[: int(succ[0]) + 1])
    states.set("episode", torch.full((states.shape[0],), index, dtype=torch.long))
    states.set("step", torch.arange(states.shape[0]))
    return states


def record_demos(
    family: TaskFamily,
    variant: str,
    num: int,
    *,
    seed: int = 0,
    variant_overrides: dict | None = None,
    max_tries: int | None = None,
    progress: bool = True,
    control_mode: str = "pd_joint_pos",
) -> tuple[TensorDict, dict]:
    """Run the family's solver until ``num`` successful episodes are recorded; returns (states, meta).

    The solver plans in joint-position control. ``control_mode`` other than ``"pd_joint_pos"`` (e.g. the
    agent's ``"pd_ee_delta_pos"``, Appendix A) replays each solved episode in a second env with that
    controller through ManiSkill's own converter (``mani_skill.trajectory.utils.actions.conversion``),
    and records that env: the states the agent's controller reaches, its actions, and the states they
    were taken in. A converted episode that does not succeed is dropped."""
    import gymnasium as gym
    import mani_skill.envs  # noqa: F401

    import drs_torchrl.envs.variants  # noqa: F401
    from drs_torchrl.envs.doctor import ensure_env_ready

    if family.backend != "maniskill":
        raise DemoError(
            f"family {family.name!r} ({family.backend}) has no motion-planning solver; drs-demos records ManiSkill families"
        )
    args = family.env_args(variant, variant_overrides)  # train/test: the split's variants, drawn per episode
    env_id, kwargs = args["env_id"], args["env_kwargs"]
    ensure_env_ready(env_id, kwargs)
    ref, solve = _solver(family)
    env = gym.make(
        env_id,
        obs_mode="state",
        control_mode="pd_joint_pos",
        num_envs=1,
        sim_backend="physx_cpu",
        render_mode=None,
        max_episode_steps=10 * family.max_episode_steps,
        **kwargs,
    )
    recorder = _Recorder(env, family.all_info_keys, family.task_observation_key)
    labeller = StageIndicator(family.stage_keys)
    target = None
    if control_mode != "pd_joint_pos":
        from mani_skill.trajectory.utils.actions.conversion import from_pd_joint_pos

        target_env = gym.make(
            env_id,
            obs_mode="state",
            control_mode=control_mode,
            num_envs=1,
            sim_backend="physx_cpu",
            render_mode=None,
            max_episode_steps=40 * family.max_episode_steps,
            **kwargs,
        )
        target = _Recorder(target_env, family.all_info_keys, family.task_observation_key)
    state_keys = [k for k in ("observation", "stage_indicators", family.task_observation_key) if k]
    episodes, lengths, seeds = [], [], []
    tries, s = 0, seed
    max_tries = max_tries or 3 * num + 10
    t0 = time.time()
    planner_said: collections.Counter = collections.Counter()  # its prints ("screw plan failed"), shown as a count
    while len(episodes) < num:
        if tries >= max_tries:
            raise RuntimeError(
                f"the solver succeeded in only {len(episodes)} of {tries} tries on {family.name}/{variant}"
            )
        tries += 1
        try:
            with library_prints(planner_said):
                solve(recorder, seed=s)
            # the planner stops as soon as it reaches the goal pose; families whose success also needs the
            # robot and object at rest (Appendix A) hold the last joint targets a few steps more
            recorder.settle(int(family.extra.get("demo_settle_steps", 0)))
        except Exception as exc:  # the planner fails on some initial states: try the next seed
            print(f"  seed {s}: solver failed ({exc.__class__.__name__}); skipping", file=sys.stderr)
            s += 1
            continue
        states, rec = recorder.states(), recorder
        if states is not None and target is not None:  # replay the solution in the agent's controller
            actions = recorder.actions()
            recorder.reset(seed=s)
            target.reset(seed=s)
            try:
                from_pd_joint_pos(control_mode, actions, recorder, target)
            except Exception as exc:
                print(
                    f"  seed {s}: conversion to {control_mode} failed ({exc.__class__.__name__}); skipping",
                    file=sys.stderr,
                )
                states = None
            else:
                states, rec = target.states(), target
        s += 1
        if states is None:
            continue
        states = _successful_episode(states, labeller, len(episodes))
        if states is None:
            continue
        states = _with_previous_states(
            states, rec._reset_obs, [k for k in state_keys if k in states.keys()] + ["stage"]
        )
        episodes.append(states)
        lengths.append(states.shape[0])
        seeds.append(s - 1)
        if progress:
            print(f"\r  {len(episodes)}/{num} demos ({time.time() - t0:.0f}s)", end="", file=sys.stderr, flush=True)
    if progress:
        print(file=sys.stderr)
    if planner_said:
        said = ", ".join(f"{text!r} x{n}" for text, n in planner_said.most_common(3))
        print(
            f"  the motion planner reported {sum(planner_said.values())} failed plans ({said}); "
            "DRS_LIBRARY_MESSAGES=1 shows them as they happen",
            file=sys.stderr,
        )
    env.close()
    if target is not None:
        target.env.close()
    data = torch.cat(episodes, 0)
    meta = {
        "format": DEMO_FORMAT,
        "version": DEMO_VERSION,
        "family": family.name,
        "env_id": env_id,
        "variant": variant,
        "variant_kwargs": kwargs,
        "stage_keys": list(family.stage_keys),
        "shapes": {
            k: int(data[k].shape[-1]) for k in ("observation", "stage_indicators", family.task_observation_key) if k
        },
        "episodes": len(episodes),
        "lengths": lengths,
        "seeds": seeds,
        "solver": ref,
        "actions": {"control_mode": control_mode, "size": int(data["action"].shape[-1])},
    }
    return data, meta


def record_policy_demos(
    policy_path: str | Path,
    variant: str | None = None,
    num: int = 100,
    *,
    seed: int = 0,
    variant_overrides: dict | None = None,
    deterministic: bool = True,
    max_episodes: int | None = None,
    progress: bool = True,
    task_observation: bool = False,
) -> tuple[TensorDict, dict]:
    """Roll out a trained ``drs-learn``/``drs-reuse`` policy until ``num`` episodes succeed; returns (states, meta).

    The env is the family's (``make_family_env``) with the run's controller, episode length and
    variant overrides (from the run's ``config.yaml`` when there is one; ``variant_overrides`` are
    applied on top). ``deterministic=False`` samples actions from the policy, which succeeds more
    often than its mean action early in training. Stops with ``RuntimeError`` after
    ``max_episodes`` (default ``20 * num``) episodes.
    """
    from omegaconf import OmegaConf
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from drs_torchrl.envs.factory import make_family_env
    from drs_torchrl.models import load_policy, read_policy_checkpoint

    file, ck = read_policy_checkpoint(policy_path)
    family = get_family(ck["family"])
    # the run's env settings, when the checkpoint sits in a run directory (RUN/checkpoints/policy.pt) of its family
    cfg_file = file.parent.parent / "config.yaml"
    env_cfg = {}
    if file.parent.name == "checkpoints" and cfg_file.is_file():
        env_cfg = OmegaConf.to_container(load_run_config(cfg_file.parent, needs=("env",))).get("env") or {}
        if env_cfg.get("family", family.name) != family.name:
            env_cfg = {}
    family = with_stages(family, env_cfg.get("stages"))  # a stage-ablation run observes only its stages
    family = with_task_observation(family, env_cfg.get("task_observation") or task_observation)
    overrides = {**(env_cfg.get("variant_overrides") or {}), **(variant_overrides or {})}
    variant = variant or env_cfg.get("split") or "train"  # default: the split the policy was trained on
    env = make_family_env(
        family,
        variant,
        variant_overrides=overrides or None,
        seed=seed,
        control_mode=env_cfg.get("control_mode"),
        max_episode_steps=env_cfg.get("max_episode_steps"),
    )
    try:
        actor, pmeta = load_policy(file, env.observation_spec, env.action_spec, family=family.name)
        keys = [
            k
            for k in ("observation", *family.all_info_keys, family.task_observation_key)
            if k and k in env.observation_spec.keys(True)
        ]
        labeller = StageIndicator(family.stage_keys)
        reward_keys = [
            k
            for k in ("observation", "stage_indicators", family.task_observation_key, *family.reward_in_keys)
            if k and k in env.observation_spec.keys(True)
        ]
        reward_keys = list(dict.fromkeys(reward_keys))
        limit = int(getattr(env.base_env, "max_episode_steps", 0) or 0)  # the env's time limit, or -1/0: unknown
        if limit <= 0:
            limit = int(env_cfg.get("max_episode_steps") or family.max_episode_steps)
        episodes, lengths, tried_ids = [], [], []
        max_episodes = int(max_episodes or 20 * num)
        tried, t0 = 0, time.time()
        mode = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
        with set_exploration_type(mode), torch.no_grad():
            while len(episodes) < num:
                if tried >= max_episodes:
                    raise RuntimeError(
                        f"the policy succeeded in only {len(episodes)} of {tried} episodes on "
                        f"{family.name}/{variant}" + ("; try --stochastic" if deterministic else "")
                    )
                td = env.rollout(limit, actor, break_when_any_done=True)
                tried += 1
                nxt = td["next"]
                states = TensorDict({k: nxt[k].clone() for k in keys}, batch_size=[td.shape[0]])
                # what (s, a) rewards such as GAIL's need: the action taken and the state it was taken in
                states.set("action", td["action"].clone().float())
                states.set(
                    "state",
                    TensorDict(
                        {k: td[k].clone() for k in (*reward_keys, "stage") if k in td.keys()}, batch_size=[td.shape[0]]
                    ),
                )
                states = _successful_episode(states, labeller, len(episodes))
                if progress:
                    print(
                        f"\r  {len(episodes) + (states is not None)}/{num} demos from {tried} episodes "
                        f"({time.time() - t0:.0f}s)",
                        end="",
                        file=sys.stderr,
                        flush=True,
                    )
                if states is None:
                    continue
                episodes.append(states)
                lengths.append(states.shape[0])
                tried_ids.append(tried - 1)
        if progress:
            print(file=sys.stderr)
    finally:
        env.close()
    args = family.env_args(variant, overrides or None)
    data = torch.cat(episodes, 0)
    meta = {
        "format": DEMO_FORMAT,
        "version": DEMO_VERSION,
        "family": family.name,
        "env_id": args.get("env_id", family.env_id),
        "variant": variant,
        "variant_kwargs": args.get("env_kwargs", {}),
        "stage_keys": list(family.stage_keys),
        "shapes": {
            k: int(data[k].shape[-1]) for k in ("observation", "stage_indicators", family.task_observation_key) if k
        },
        "episodes": len(episodes),
        "lengths": lengths,
        "seeds": [seed] * len(episodes),
        "episode_indices": tried_ids,
        "max_episode_steps": limit,
        "solver": f"policy:{file} (frames {pmeta.get('frames')}, {'deterministic' if deterministic else 'stochastic'})",
        "episodes_tried": tried,
        "success_rate": len(episodes) / tried,
        # actions are the agent's own (its controller), with the states they were taken in ("state")
        "actions": {
            "control_mode": env_cfg.get("control_mode") or args.get("control_mode") or family.control_mode,
            "size": int(data["action"].shape[-1]),
        },
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
        obs, info = self.env.reset(**kwargs)
        self._reset_obs = torch.as_tensor(obs).reshape(-1).float()
        return obs, info

    def settle(self, steps: int) -> None:
        """Repeat the last action (joint targets) until success, for at most ``steps`` steps."""
        for _ in range(steps):
            if not self._rows or bool(self._rows[-1]["success"].any()):
                return
            self.step(self._last_action)

    def step(self, action):
        self._last_action = action
        obs, reward, terminated, truncated, info = self.env.step(action)
        row = {
            "observation": torch.as_tensor(obs).reshape(-1).float(),
            "action": torch.as_tensor(action).reshape(-1).float(),
        }
        for k in self.info_keys:
            row[k] = torch.as_tensor(info[k]).reshape(1).bool()
        if self.task_key:  # the robot-agnostic reward input of families such as cross_robot
            row[self.task_key] = self.env.unwrapped.task_observation().reshape(-1).float()
        self._rows.append(row)
        return obs, reward, terminated, truncated, info

    def states(self) -> TensorDict | None:
        if not self._rows:
            return None
        return TensorDict(
            {k: torch.stack([r[k] for r in self._rows]) for k in self._rows[0]}, batch_size=[len(self._rows)]
        )

    def actions(self) -> list:
        return [r["action"].numpy() for r in self._rows]


def _with_previous_states(states: TensorDict, reset_obs: torch.Tensor, keys) -> TensorDict:
    """Add ``state``: for each row, the reward inputs and stage of the state its ``action`` was taken in
    (the previous row's; for the first, the reset observation at stage 0)."""
    first = TensorDict(
        {k: (reset_obs if k == "observation" else torch.zeros_like(states[k][0])) for k in keys}, batch_size=[]
    )
    prev = torch.cat([first.unsqueeze(0), states[:-1].select(*keys)], 0)
    states.set("state", prev)
    return states


def check_demos_out(path: str | Path) -> Path:
    """``path`` if demonstrations can be written there: new, or demonstrations to replace (never another folder)."""
    path = check_writable(path, "--out", folder=True)
    if path.exists() and any(path.iterdir()) and not (path / "meta.json").is_file():
        raise DemoError(
            f"--out {path} is a folder that does not hold demonstrations; give a new path such as {path / 'my.demos'}"
        )
    return path


def save_demos(states: TensorDict, meta: dict, path: str | Path) -> Path:
    path = check_demos_out(path)
    tmp = path.with_name(path.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    ensure_free(tmp, nbytes(states), "the demonstrations")  # a memory map on a full disk faults (SIGBUS)
    try:
        with space_errors(tmp, "the demonstrations"):
            tmp.mkdir(parents=True)
            states.memmap(tmp / "states", num_threads=0)
            (tmp / "meta.json").write_text(json.dumps(meta, indent=2))
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if path.exists():
        shutil.rmtree(path)
    tmp.rename(path)
    return path


def load_demos(path: str | Path) -> tuple[list[TensorDict], dict]:
    """Episodes (each a ``(T,)`` TensorDict of states) and the file's metadata."""
    path = Path(path)
    if not (path / "meta.json").is_file():
        raise DemoError(f"{path} is not a drs-torchrl demonstrations directory (no meta.json); make one with drs-demos")
    try:
        meta = json.loads((path / "meta.json").read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise DemoError(
            f"{path / 'meta.json'} is damaged ({exc.__class__.__name__}: {exc}); record the "
            "demonstrations again with drs-demos"
        ) from None
    if not isinstance(meta, dict) or meta.get("format") != DEMO_FORMAT:
        raise DemoError(f"{path}: unknown format {meta.get('format')!r}")
    if int(meta.get("version", 99)) > DEMO_VERSION:
        raise DemoError(
            f"{path} has demo format version {meta['version']}, newer than this drs-torchrl reads ({DEMO_VERSION})"
        )
    try:
        states = load_memmap_checked(path / "states").clone()
    except Exception as exc:
        raise DemoError(f"{path}: the states cannot be read (corrupt or truncated?): {exc}") from exc
    missing = [k for k in ("family", "stage_keys", "shapes") if k not in meta]
    if missing:
        raise DemoError(
            f"{path / 'meta.json'} is damaged: it lacks {missing}; record the demonstrations again with drs-demos"
        )
    ep = states["episode"]
    bounds = torch.cat([torch.tensor([0]), (ep[1:] != ep[:-1]).nonzero().reshape(-1) + 1, torch.tensor([ep.numel()])])
    episodes = [states[int(a) : int(b)] for a, b in zip(bounds[:-1], bounds[1:])]
    return episodes, meta


def restage_demos(episodes: list[TensorDict], meta: dict, stage_keys) -> tuple[list[TensorDict], dict]:
    """The same demonstrations under a subset of their stage indicators (a stage ablation, ``env.stages``).

    Every recorded indicator is kept per state, so each state's stage and monotone indicators are
    recomputed from ``stage_keys``, and so are those of ``"state"`` (the state each action was taken
    in: the previous row's; the first row's from its recorded indicators' columns of ``stage_keys``).
    """
    stage_keys, recorded = list(stage_keys), list(meta["stage_keys"])
    missing = [k for k in stage_keys if k not in recorded]
    if missing:
        raise DemoError(f"the demonstrations record the stage indicators {recorded}; {missing} are not among them")
    labeller = StageIndicator(stage_keys)
    cols = [recorded.index(k) for k in stage_keys]
    out = []
    for ep in episodes:
        ep = labeller(ep.clone())
        prev = ep.get("state", None)
        if prev is not None and "stage_indicators" in prev.keys():
            head = monotone_indicators(prev.get("stage_indicators")[:1, cols])
            prev.set("stage_indicators", torch.cat([head.to(torch.float32), ep.get("stage_indicators")[:-1]], 0))
            if "stage" in prev.keys():
                prev.set(
                    "stage",
                    torch.cat([head.sum(-1, keepdim=True), ep.get("stage")[:-1]], 0).to(prev.get("stage").dtype),
                )
        out.append(ep)
    shapes = {**meta["shapes"], "stage_indicators": len(stage_keys)}
    return out, {**meta, "stage_keys": stage_keys, "shapes": shapes}


def variant_mismatches(meta: dict, overrides: dict | None) -> list[str]:
    """The run's variant overrides (``env.variant_overrides``) that the demonstrations were recorded without.

    Their stage labels follow the recording's task definition (e.g. a "placed" threshold of 2.5 cm,
    where the run's is 5 cm), so such a mismatch relabels nothing and is worth a warning.
    """
    recorded = meta.get("variant_kwargs") or {}
    variants = recorded.get("variants") if isinstance(recorded.get("variants"), list) else [recorded]
    out = []
    for key, value in (overrides or {}).items():
        have = sorted({repr(v[key]) if key in v else "the variant's default" for v in variants})
        if have != [repr(value)]:
            out.append(f"{key}={value!r} (recorded with {', '.join(have)})")
    return out


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


# ---------------------------------------------------------------- ManiSkill trajectory files (.h5 + .json)
def _h5_group_to_numpy(group) -> dict:
    """An h5py group of arrays (ManiSkill's nested ``env_states``) as nested dicts of numpy arrays."""
    import h5py

    return {k: _h5_group_to_numpy(v) if isinstance(v, h5py.Group) else v[()] for k, v in group.items()}


def _index_state(states: dict, t: int) -> dict:
    return {k: _index_state(v, t) if isinstance(v, dict) else v[t] for k, v in states.items()}


def _state_error(recorded: dict, current: dict) -> float:
    """Largest absolute difference between a recorded state and the simulator's (shared leaves only)."""
    err = 0.0
    for k, v in recorded.items():
        if k not in current:
            continue
        if isinstance(v, dict):
            err = max(err, _state_error(v, current[k]))
        else:
            cur = torch.as_tensor(current[k]).reshape(-1).double().cpu()
            rec = torch.as_tensor(v).reshape(-1).double()
            if cur.shape == rec.shape and cur.numel():
                err = max(err, float((cur - rec).abs().max()))
    return err


def _leaf_paths(state: dict, prefix: str = "") -> set[str]:
    out = set()
    for k, v in state.items():
        out |= _leaf_paths(v, f"{prefix}{k}/") if isinstance(v, dict) else {prefix + k}
    return out


def _recorded_variant_check(family: TaskFamily, env_kwargs: dict, recorded: dict) -> list[str]:
    """Variant parameters the recording fixes differently from ``env_kwargs`` (one message each)."""
    out = []
    for k, want in env_kwargs.items():
        if k in recorded and recorded[k] != want:
            try:
                if float(recorded[k]) == float(want):
                    continue
            except (TypeError, ValueError):
                pass
            out.append(f"{k}={recorded[k]!r} (the variant has {k}={want!r})")
    return out


def _env_class(env_id: str):
    import gymnasium as gym

    spec = gym.registry.get(env_id)
    if spec is None:
        return None
    ep = spec.entry_point
    if isinstance(ep, str):
        module, _, name = ep.partition(":")
        ep = getattr(importlib.import_module(module), name)
    return ep if isinstance(ep, type) else None


def _replayable_env_id(env_id: str, recorded_id: str) -> bool:
    """``env_id`` can replay ``recorded_id``'s trajectories: the same env, or one derived from it
    (``PickCubeSized-v1`` is ManiSkill's ``PickCube-v1`` with the cube size as a parameter)."""
    if recorded_id == env_id:
        return True
    mine, theirs = _env_class(env_id), _env_class(recorded_id)
    return mine is not None and theirs is not None and issubclass(mine, theirs)


def load_maniskill_h5(
    path: str | Path,
    family: TaskFamily,
    variant: str = "train",
    *,
    num: int | None = None,
    variant_overrides: dict | None = None,
    state_tolerance: float = 1e-4,
    progress: bool = True,
) -> tuple[TensorDict, dict]:
    """Convert a ManiSkill trajectory file (``X.h5`` + ``X.json``) into demonstrations (states, meta).

    Algorithm 1 (line 3) of the DrS paper seeds the top stage buffer with demonstrations; ManiSkill
    ships its datasets as trajectory files written by ``mani_skill.utils.wrappers.RecordEpisode``:
    per episode the actions ``[T, A]`` and the env states ``[T+1, ...]`` (nested dicts), with the env
    id, env kwargs and each episode's seed, reset kwargs and control mode in the JSON. Observations
    are optional there and come in whatever ``obs_mode`` the dataset used, so they are not read:
    each episode is replayed in the family's env (``obs_mode="state"``, the recorded control mode,
    CPU simulation). It is reset with the episode's reset kwargs, set to the first recorded state,
    and then every recorded action is stepped; whenever the stepped state differs from the recorded
    next state by more than ``state_tolerance`` the simulator is set onto the recorded one
    (as ManiSkill's ``--use-env-states`` replay does at every step). Observations and stage
    indicators are read from the steps, so contact-based indicators such as ``is_grasped`` come
    from the physics. Correcting only on drift keeps a deterministic replay exact: setting a state
    drops PhysX's contact caches, so the next contact-rich step differs slightly from the recording.
    ``meta["replay"]`` reports the number of corrections, the largest state difference seen, the
    largest difference to the file's own observations (when it has state observations) and the
    steps whose success label differs from the file's.

    Episodes are cut at their first successful state; episodes that never succeed are skipped
    (their number is ``meta["replay"]["skipped_unsuccessful"]``). Raises :class:`DemoError` for a
    missing file, an env id the family cannot replay, variant parameters that contradict the
    recording, a control mode the env does not have, or states that do not fit its scene.
    """
    import gymnasium as gym
    import h5py
    import mani_skill.envs  # noqa: F401

    import drs_torchrl.envs.variants  # noqa: F401
    from drs_torchrl.envs.doctor import ensure_env_ready

    h5_path = Path(path)
    json_path = h5_path.with_suffix(".json")
    if h5_path.suffix != ".h5":
        raise DemoError(f"{h5_path}: expected a ManiSkill trajectory file ending in .h5 (with its .json beside it)")
    if not h5_path.is_file():
        raise DemoError(f"{h5_path}: no such trajectory file")
    if not json_path.is_file():
        raise DemoError(
            f"{h5_path}: its metadata {json_path.name} is missing (ManiSkill writes X.h5 and X.json together)"
        )
    if family.backend != "maniskill":
        raise DemoError(f"family {family.name!r} is not a ManiSkill family; ManiSkill trajectory files do not apply")
    try:
        info = json.loads(json_path.read_text())
        env_info, episodes = info["env_info"], list(info["episodes"])
        recorded_id, recorded_kwargs = env_info["env_id"], dict(env_info.get("env_kwargs") or {})
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise DemoError(
            f"{json_path}: not ManiSkill trajectory metadata (needs env_info.env_id and episodes): {exc}"
        ) from exc
    kwargs = dict(family.variant_kwargs(variant, variant_overrides))
    env_id = kwargs.pop("env_id", family.env_id)  # a variant may name its own env
    kwargs.pop("control_mode", None)  # the recorded actions dictate the controller
    if not _replayable_env_id(env_id, recorded_id):
        raise DemoError(
            f"{h5_path} was recorded in {recorded_id!r}, but family {family.name!r} ({variant}) runs "
            f"{env_id!r}; convert it for a family whose env is {recorded_id!r}"
        )
    clash = _recorded_variant_check(family, kwargs, recorded_kwargs)
    if clash:
        raise DemoError(
            f"{h5_path} was recorded with " + ", ".join(clash) + f"; pick the matching variant of "
            f"{family.name!r} ({sorted(family.variants)}) or set it with variant overrides"
        )
    unverified = sorted(k for k in kwargs if k not in recorded_kwargs)
    if unverified and progress:
        print(
            f"  note: the recording does not state {unverified}; assuming variant {variant!r} ({kwargs})",
            file=sys.stderr,
        )
    if not episodes:
        raise DemoError(f"{json_path} lists no episodes")
    ensure_env_ready(env_id, kwargs)

    envs: dict[str, Any] = {}
    longest = max(int(e.get("elapsed_steps", 0)) for e in episodes) + 1

    def env_for(control_mode: str):
        if control_mode not in envs:
            try:
                envs[control_mode] = gym.make(
                    env_id,
                    obs_mode="state",
                    control_mode=control_mode,
                    num_envs=1,
                    sim_backend="physx_cpu",
                    render_mode=None,
                    reward_mode="sparse",
                    max_episode_steps=longest,
                    **kwargs,
                )
            except Exception as exc:  # ManiSkill asserts on an unknown control mode
                raise DemoError(
                    f"{h5_path}: its episodes use control mode {control_mode!r}, which {env_id} "
                    f"cannot build ({exc.__class__.__name__}: {exc}); convert them with ManiSkill's "
                    "replay_trajectory --target-control-mode to a mode the robot has"
                ) from exc
        return envs[control_mode]

    labeller = StageIndicator(family.stage_keys)
    task_key = getattr(family, "task_observation_key", None)  # robot-agnostic reward input, if the family has one
    out, lengths, seeds, ids = [], [], [], []
    skipped, max_err, obs_err, corrections, success_mismatch = 0, 0.0, None, 0, 0
    t0 = time.time()
    try:
        with h5py.File(h5_path, "r") as h5:
            for ep in episodes:
                if num is not None and len(out) >= num:
                    break
                eid = ep.get("episode_id")
                group = h5.get(f"traj_{eid}")
                if group is None or "actions" not in group:
                    raise DemoError(f"{h5_path}: the json lists episode {eid} but the file has no traj_{eid}/actions")
                control_mode = ep.get("control_mode") or recorded_kwargs.get("control_mode")
                if not control_mode:
                    raise DemoError(f"{h5_path}: episode {eid} does not say which control mode its actions are for")
                env = env_for(control_mode)
                base = env.unwrapped
                reset_kwargs = dict(ep.get("reset_kwargs") or {})
                seed = reset_kwargs.get("seed", ep.get("episode_seed"))
                if isinstance(seed, list):
                    seed = seed[0]
                reset_kwargs["seed"] = seed
                env.reset(**reset_kwargs)
                actions = group["actions"][()]
                states = _h5_group_to_numpy(group["env_states"]) if "env_states" in group else None
                if states is not None:
                    mine = _leaf_paths(base.get_state_dict())
                    theirs = {p for p in _leaf_paths(states) if not p.startswith("controller/")}
                    if not theirs <= mine:
                        raise DemoError(
                            f"{h5_path}: the recorded states of episode {eid} name entities that {env_id} "
                            f"with {kwargs} does not have: {sorted(theirs - mine)} (the env has {sorted(mine)})"
                        )
                try:
                    if states is not None:  # the reset normally reproduces it; setting it would drop contact caches
                        first = _index_state(states, 0)
                        err = _state_error(first, base.get_state_dict())
                        max_err = max(max_err, err)
                        if err > state_tolerance:
                            base.set_state_dict(first)
                            corrections += 1
                except Exception as exc:
                    raise DemoError(
                        f"{h5_path}: the recorded states of episode {eid} do not fit {env_id} with "
                        f"{kwargs} ({exc.__class__.__name__}: {exc})"
                    ) from exc
                rows = []
                rec_success = group["success"][()].reshape(-1) if "success" in group else None
                for t, a in enumerate(actions):
                    obs, _, _, _, step_info = env.step(torch.as_tensor(a).reshape(1, -1))
                    row = {"observation": torch.as_tensor(obs).reshape(-1).float().cpu()}
                    for k in family.all_info_keys:
                        if k not in step_info:
                            raise DemoError(f"{env_id} does not report the indicator {k!r}")
                        row[k] = torch.as_tensor(step_info[k]).reshape(1).bool().cpu()
                    if task_key:
                        row[task_key] = torch.as_tensor(base.task_observation()).reshape(-1).float().cpu()
                    rows.append(row)
                    if rec_success is not None and t < len(rec_success) and "success" in row:
                        success_mismatch += int(bool(row["success"]) != bool(rec_success[t]))
                    if states is not None:
                        target = _index_state(states, t + 1)
                        err = _state_error(target, base.get_state_dict())
                        max_err = max(max_err, err)
                        if err > state_tolerance:
                            base.set_state_dict(target)
                            corrections += 1
                if "obs" in group and isinstance(group["obs"], h5py.Dataset) and rows:  # state observations
                    rec = torch.as_tensor(group["obs"][()]).float()
                    mine = torch.stack([r["observation"] for r in rows])
                    if rec.ndim == 2 and tuple(rec.shape) == (len(rows) + 1, mine.shape[-1]):
                        obs_err = max(obs_err or 0.0, float((rec[1:] - mine).abs().max()))
                if not rows:
                    skipped += 1
                    continue
                ep_states = TensorDict({k: torch.stack([r[k] for r in rows]) for k in rows[0]}, batch_size=[len(rows)])
                ep_states = _successful_episode(ep_states, labeller, len(out))
                if ep_states is None:
                    skipped += 1
                    continue
                out.append(ep_states)
                lengths.append(ep_states.shape[0])
                seeds.append(None if seed is None else int(seed))
                ids.append(eid)
                if progress:
                    print(
                        f"\r  {len(out)} demos from {h5_path.name} ({time.time() - t0:.0f}s)",
                        end="",
                        file=sys.stderr,
                        flush=True,
                    )
    except OSError as exc:
        raise DemoError(f"{h5_path}: cannot be read as HDF5 ({exc})") from exc
    finally:
        for env in envs.values():
            env.close()
        if progress:
            print(file=sys.stderr)
    if not out:
        raise DemoError(f"{h5_path}: none of its {len(episodes)} episodes reaches success in {family.name}/{variant}")
    data = torch.cat(out, 0)
    meta = {
        "format": DEMO_FORMAT,
        "version": DEMO_VERSION,
        "family": family.name,
        "env_id": env_id,
        "variant": variant,
        "variant_kwargs": kwargs,
        "stage_keys": list(family.stage_keys),
        "shapes": {k: int(data[k].shape[-1]) for k in ("observation", "stage_indicators", task_key) if k},
        "episodes": len(out),
        "lengths": lengths,
        "seeds": seeds,
        "solver": f"maniskill-h5:{h5_path.name}",
        "replay": {
            "source": str(h5_path),
            "recorded_env_id": recorded_id,
            "source_type": info.get("source_type"),
            "episode_ids": ids,
            "skipped_unsuccessful": skipped,
            "unverified_variant_keys": unverified,
            "state_tolerance": state_tolerance,
            "state_corrections": corrections,
            "max_state_error": max_err,
            "max_recorded_obs_error": obs_err,
            "success_label_mismatches": success_mismatch,
        },
    }
    return data, meta


@console_script("drs-demos")
def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="drs-demos",
        description="generate demonstrations with ManiSkill's motion planners, "
        "record a trained policy's successful episodes (--from-policy), "
        "or convert a ManiSkill trajectory file (--from-h5)",
    )
    p.add_argument("--family", default="pick_cube")
    p.add_argument(
        "--variant",
        default=None,
        help="variant name, or train/test (default: train; with --from-policy, the split the run trained on)",
    )
    p.add_argument("--num", type=int, default=None, help="default: 100 recorded; all successful ones of --from-h5")
    p.add_argument(
        "--from-h5",
        type=Path,
        default=None,
        metavar="PATH.h5",
        help="convert ManiSkill's trajectory file PATH.h5 (+ PATH.json) by replaying it in the family's env",
    )
    p.add_argument(
        "--from-policy",
        default=None,
        metavar="RUN_DIR",
        help="roll out a drs-learn/drs-reuse run's policy (RUN_DIR or its policy.pt) and keep its successful "
        "episodes, as the paper's demonstrations (any family; the family comes from the checkpoint)",
    )
    p.add_argument("--stochastic", action="store_true", help="--from-policy: sample actions instead of the mean action")
    p.add_argument(
        "--max-episodes", type=int, default=None, help="--from-policy: give up after this many (default 20 x --num)"
    )
    p.add_argument(
        "--override",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a variant parameter for every recorded episode, e.g. placed_thresh=0.05 (the placed-threshold "
        "ablations) or max_steps=150 (repeatable; not with --from-h5)",
    )
    p.add_argument(
        "--control-mode",
        default=None,
        help="solver demonstrations: replay them in this controller "
        "(e.g. pd_ee_delta_pos, the agent's; default: the family's) with ManiSkill's converter; "
        "pd_joint_pos keeps the planner's own",
    )
    p.add_argument(
        "--task-observation",
        action="store_true",
        help="also record the env's robot-agnostic task state "
        "(key task_observation), for rewards learned with env.task_observation=true "
        "reward.in_keys=[task_observation,stage_indicators]",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        help="default: demos/<family>-<variant>.demos (-policy.demos with --from-policy)",
    )
    a = p.parse_args(argv)
    if a.num is not None and a.num < 1:
        p.error("--num must be >= 1")
    if a.from_policy is not None and a.from_h5 is not None:
        p.error("--from-policy and --from-h5 are two different sources; give one")
    import yaml

    overrides = {}
    for item in a.override:
        key, eq, value = item.partition("=")
        if not eq or not key:
            p.error(f"--override takes KEY=VALUE, got {item!r}")
        overrides[key] = yaml.safe_load(value)
    if overrides and a.from_h5 is not None:
        p.error("--override applies to recording (the planner or --from-policy), not to --from-h5")
    try:
        if a.out is not None:
            check_demos_out(a.out)  # now, not after minutes of recording
        if a.from_policy is not None:  # a bad checkpoint raises PolicyCheckpointError, a ValueError
            states, meta = record_policy_demos(
                a.from_policy,
                a.variant,
                a.num or 100,
                seed=a.seed,
                variant_overrides=overrides,
                deterministic=not a.stochastic,
                max_episodes=a.max_episodes,
                task_observation=a.task_observation,
            )
            fam = get_family(meta["family"])
        else:
            fam = with_task_observation(get_family(a.family), a.task_observation)
            if a.from_h5 is not None:
                states, meta = load_maniskill_h5(a.from_h5, fam, a.variant or "train", num=a.num)
            else:
                states, meta = record_demos(
                    fam,
                    a.variant or "train",
                    a.num or 100,
                    seed=a.seed,
                    variant_overrides=overrides or None,
                    control_mode=a.control_mode or fam.control_mode or "pd_joint_pos",
                )
        out = a.out or Path("demos") / f"{fam.name}-{meta['variant']}{'-policy' if a.from_policy else ''}.demos"
    except (KeyError, UserError, RuntimeError, ValueError, TypeError) as exc:
        print(f"drs-demos: error: {exc.args[0] if isinstance(exc, KeyError) else exc}", file=sys.stderr)
        return 2
    save_demos(states, meta, out)
    lengths = meta["lengths"]
    print(f"{meta['episodes']} demonstrations ({sum(lengths)} states, length {min(lengths)}-{max(lengths)}) -> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
