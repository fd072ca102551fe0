"""Gymnasium task families (``TaskFamily.backend == "gymnasium"``) as TorchRL envs.

DrS paper, Appendix G: the one-stage version of DrS on MuJoCo locomotion (HalfCheetah). The
success signal there is not an env flag but a property of the episode so far ("accumulated dense
reward above 4800"), and the test tasks change the dynamics (1.5x damping on the front leg's
joints). Both are small Gymnasium wrappers here; TorchRL's :class:`~torchrl.envs.GymWrapper` then
turns the env into a TorchRL env whose TensorDicts look like the ManiSkill families' ones:

* ``"observation"``: the flat state, float32;
* the family's stage indicators (here ``"success"``) as bool ``(*batch, 1)`` entries, read from the
  step's ``info`` by a :class:`~torchrl.envs.gym_like.default_info_dict_reader`, so that
  :class:`~drs_torchrl.transforms.stages.StageIndicator` works unchanged;
* ``"reward"``: the env's own reward (``reward_mode="dense"``/``"normalized_dense"``, the paper's
  human-engineered baseline) or the success flag (``"sparse"``).

A family variant's keyword arguments may hold two parameters that these wrappers consume,
``joint_damping_scale`` (``{joint name: factor}``) and ``success_return`` (the threshold; default
``family.extra["success_return"]``); every other one goes to ``gymnasium.make`` (e.g. HalfCheetah's
``ctrl_cost_weight``).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping

import gymnasium as gym
import numpy as np
import torch
from torchrl.data import Categorical, Composite
from torchrl.envs import EnvBase, GymWrapper, ParallelEnv, SerialEnv
from torchrl.envs.gym_like import default_info_dict_reader

from drs_torchrl.runtime.errors import UserError
from drs_torchrl.tasks import TaskFamily

WRAPPER_KWARGS = ("joint_damping_scale", "success_return")
REWARD_MODES = ("dense", "normalized_dense", "sparse")


class GymFamilyError(UserError, ValueError):
    """A Gymnasium family or variant that cannot be built, with the reason."""


class JointDampingScale(gym.Wrapper):
    """Multiply the damping of named MuJoCo joints (the test variants of Appendix G).

    Writes ``model.dof_damping`` once at construction: the MuJoCo model persists across resets.
    ``original_damping`` / ``damping`` expose the per-DoF values before and after.
    """

    def __init__(self, env: gym.Env, scale: Mapping[str, float]):
        super().__init__(env)
        import mujoco

        model = getattr(env.unwrapped, "model", None)
        if model is None or not hasattr(model, "dof_damping"):
            raise GymFamilyError(f"{env.spec.id if env.spec else env}: joint_damping_scale needs a MuJoCo env")
        self.original_damping = np.array(model.dof_damping, copy=True)
        names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(model.njnt)]
        unknown = sorted(set(scale) - set(names))
        if unknown:
            raise GymFamilyError(f"joint_damping_scale names unknown joints {unknown}; the model's joints are {names}")
        for name, factor in scale.items():
            j = names.index(name)
            adr, n = int(model.jnt_dofadr[j]), _joint_dofs(int(model.jnt_type[j]))
            model.dof_damping[adr : adr + n] = self.original_damping[adr : adr + n] * float(factor)

    @property
    def damping(self) -> np.ndarray:
        return np.array(self.env.unwrapped.model.dof_damping, copy=True)


def _joint_dofs(jnt_type: int) -> int:
    # mjtJoint: free (6 dofs), ball (3), slide (1), hinge (1)
    return {0: 6, 1: 3}.get(jnt_type, 1)


class ReturnThresholdSuccess(gym.Wrapper):
    """Success = the running episode return has passed ``threshold`` (latched until the next reset).

    The paper's success signal for HalfCheetah (Appendix G: accumulated dense reward above 4800).
    Writes ``info[success_key]`` (a ``(1,)`` bool array) and ``info["episode_return"]`` at reset and
    every step, casts observations to float32, and with ``reward_mode="sparse"`` replaces the
    reward with the success flag.
    """

    def __init__(self, env: gym.Env, threshold: float, *, success_key: str = "success", reward_mode: str = "dense"):
        super().__init__(env)
        if reward_mode not in REWARD_MODES:
            raise GymFamilyError(
                f"reward_mode must be one of {REWARD_MODES} for a Gymnasium family, got {reward_mode!r}"
            )
        self.threshold, self.success_key, self.reward_mode = float(threshold), success_key, reward_mode
        space = env.observation_space
        if not isinstance(space, gym.spaces.Box) or len(space.shape) != 1:
            raise GymFamilyError(f"expected a flat Box observation, got {space}")
        self.observation_space = gym.spaces.Box(
            space.low.astype(np.float32), space.high.astype(np.float32), dtype=np.float32
        )
        self._return, self._success = 0.0, False

    def _info(self, info: dict) -> dict:
        info = dict(info)
        info[self.success_key] = np.array([self._success])
        info["episode_return"] = np.array([self._return], dtype=np.float32)
        return info

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self._return, self._success = 0.0, False
        return obs.astype(np.float32), self._info(info)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._return += float(reward)
        self._success = self._success or self._return > self.threshold
        if self.reward_mode == "sparse":
            reward = float(self._success)
        return obs.astype(np.float32), reward, terminated, truncated, self._info(info)


def split_variant_kwargs(family: TaskFamily, env_kwargs: Mapping) -> tuple[dict, dict[str, float], float]:
    """(``gymnasium.make`` kwargs, joint damping scales, success threshold) of a variant's kwargs."""
    kw = dict(env_kwargs or {})
    scale = dict(kw.pop("joint_damping_scale", None) or {})
    threshold = kw.pop("success_return", family.extra.get("success_return"))
    if threshold is None:
        raise GymFamilyError(f"family {family.name!r} needs a success threshold: set success_return")
    return kw, {str(k): float(v) for k, v in scale.items()}, float(threshold)


def _route_mujoco_warnings() -> None:
    """Send MuJoCo's warnings to Python's ``warnings`` instead of stderr plus a ``MUJOCO_LOG.TXT`` in
    the working directory (HalfCheetah's XML triggers a deprecation warning at every load). Leaves a
    handler that someone else installed alone."""
    try:
        import mujoco
    except ImportError:
        return
    if mujoco.get_mju_user_warning() is None:
        mujoco.set_mju_user_warning(_mujoco_warning)


def _mujoco_warning(msg: str) -> None:
    import warnings

    if "settotalmass" not in msg:
        warnings.warn(f"MuJoCo: {msg}", RuntimeWarning, stacklevel=2)


def make_gym_env(
    family: TaskFamily,
    env_kwargs: Mapping | None = None,
    *,
    reward_mode: str = "dense",
    max_episode_steps: int | None = None,
) -> gym.Env:
    """The wrapped Gymnasium env of one variant (variant kwargs as from ``family.variant_kwargs``)."""
    make_kwargs, scale, threshold = split_variant_kwargs(family, env_kwargs or {})
    _route_mujoco_warnings()
    try:
        env = gym.make(
            family.env_id, max_episode_steps=int(max_episode_steps or family.max_episode_steps), **make_kwargs
        )
    except gym.error.DependencyNotInstalled as exc:
        raise GymFamilyError(
            f"{family.env_id} needs MuJoCo: pip install 'drs-torchrl[locomotion]' (or bin/setup.sh). ({exc})"
        ) from exc
    if scale:
        env = JointDampingScale(env, scale)
    return ReturnThresholdSuccess(env, threshold, success_key=family.stage_keys[-1], reward_mode=reward_mode)


def make_torchrl_env(
    family: TaskFamily,
    env_kwargs: Mapping | None = None,
    *,
    reward_mode: str = "dense",
    max_episode_steps: int | None = None,
    device: str | torch.device = "cpu",
) -> GymWrapper:
    """One variant as a TorchRL :class:`~torchrl.envs.GymWrapper`, indicators read from ``info``."""
    env = GymWrapper(
        make_gym_env(family, env_kwargs, reward_mode=reward_mode, max_episode_steps=max_episode_steps), device=device
    )
    keys = list(family.all_info_keys)
    spec = Composite({k: Categorical(2, shape=(1,), dtype=torch.bool) for k in keys}, shape=[])
    env.set_info_dict_reader(default_info_dict_reader(keys, spec=spec))
    return env


def _worker_env(*args, **kwargs) -> GymWrapper:
    """An env in a ParallelEnv worker: the trainer, not the worker, handles Ctrl-C."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    return make_torchrl_env(*args, **kwargs)


def make_gym_family_base(
    family: TaskFamily,
    env_kwargs: Mapping | None,
    *,
    reward_mode: str = "dense",
    max_episode_steps: int | None = None,
    num_envs: int = 1,
    cpu_batching: str = "serial",
    sim_backend: str = "physx_cpu",
    control_mode: str | None = None,
) -> EnvBase:
    """The base env of ``make_family_env`` for a Gymnasium family (before the stage transform).

    Gymnasium envs simulate on the CPU, one per TorchRL sub-env: ``num_envs > 1`` batches them with
    :class:`~torchrl.envs.SerialEnv` (``cpu_batching="serial"``) or :class:`~torchrl.envs.ParallelEnv`.
    """
    if sim_backend not in ("physx_cpu", "cpu", "auto"):
        raise GymFamilyError(
            f"family {family.name!r} is a Gymnasium (MuJoCo) env: it runs on the CPU; "
            f"sim_backend={sim_backend!r} does not apply (leave env.sim_backend=physx_cpu)"
        )
    if control_mode is not None:
        raise GymFamilyError(
            f"family {family.name!r} is a Gymnasium env without controller choices; "
            f"leave env.control_mode=null (got {control_mode!r})"
        )
    if reward_mode not in REWARD_MODES:
        raise GymFamilyError(f"reward_mode must be one of {REWARD_MODES} for a Gymnasium family, got {reward_mode!r}")
    kw = {"reward_mode": reward_mode, "max_episode_steps": max_episode_steps}
    if num_envs <= 1:
        return make_torchrl_env(family, env_kwargs, **kw)
    if cpu_batching == "parallel":
        return ParallelEnv(num_envs, functools.partial(_worker_env, family, dict(env_kwargs or {}), **kw))
    return SerialEnv(num_envs, functools.partial(make_torchrl_env, family, dict(env_kwargs or {}), **kw))
