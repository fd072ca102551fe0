"""Demonstrations from ManiSkill's motion-planning solvers (``drs-demos --family F``).

The solvers plan in joint-position control; the state observation is the same under every controller,
so the reward (which reads states only) can learn from them whatever the agent's controller is.
"""

from __future__ import annotations

import collections
import importlib
import sys
import time

import torch
from tensordict import TensorDict

from drs_torchrl.runtime.console import library_prints
from drs_torchrl.demos.store import DemoError, cut_at_success, demo_meta
from drs_torchrl.tasks import TaskFamily
from drs_torchrl.transforms.stages import StageIndicator


def _solver(family: TaskFamily):
    ref = family.extra.get("demo_solver")
    if not ref:
        raise DemoError(
            f"family {family.name!r} has no motion-planning solver; load ManiSkill trajectories or record your own"
        )
    module, _, fn = ref.partition(":")
    return ref, getattr(importlib.import_module(module), fn)


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
        states = cut_at_success(states, labeller, len(episodes))
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
    meta = demo_meta(
        family,
        data,
        env_id=env_id,
        variant=variant,
        variant_kwargs=kwargs,
        lengths=lengths,
        seeds=seeds,
        solver=ref,
        actions={"control_mode": control_mode, "size": int(data["action"].shape[-1])},
    )
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
