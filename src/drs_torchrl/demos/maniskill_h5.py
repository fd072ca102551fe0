"""ManiSkill trajectory files (``X.h5`` + ``X.json``) as demonstrations (``drs-demos --from-h5``)."""

from __future__ import annotations

import importlib
import json
import sys
import time
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict

from drs_torchrl.demos.store import DemoError, cut_at_success, demo_meta
from drs_torchrl.tasks import TaskFamily
from drs_torchrl.transforms.stages import StageIndicator


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
                ep_states = cut_at_success(ep_states, labeller, len(out))
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
    meta = demo_meta(
        family,
        data,
        env_id=env_id,
        variant=variant,
        variant_kwargs=kwargs,
        lengths=lengths,
        seeds=seeds,
        solver=f"maniskill-h5:{h5_path.name}",
        replay={
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
    )
    return data, meta
