"""ManiSkill3 as a TorchRL environment.

:class:`ManiSkillEnv` wraps a ManiSkill3 gymnasium environment (state observations) in a
:class:`torchrl.envs.EnvBase` with validated specs. ManiSkill returns batched torch tensors even
for one CPU environment, which TorchRL's ``GymWrapper`` cannot spec; this wrapper keeps the batch
explicit instead:

* CPU simulation (``sim_backend="physx_cpu"``): one env per process, ``batch_size=[]``. Several CPU
  envs go through TorchRL's :class:`~torchrl.envs.SerialEnv` / :class:`~torchrl.envs.ParallelEnv`.
* GPU simulation (``sim_backend="physx_cuda"``): ``num_envs`` parallel envs in one process,
  ``batch_size=[num_envs]``, partial resets through ManiSkill's ``env_idx`` reset option.

The info entries that stage indicators need (``is_grasped``, ``is_obj_placed``, ``success``...) are
written into the TensorDict as boolean entries of shape ``(*batch, 1)``.

Task families (DrS Sec. 3) hand the env the variants of a split; the drs-torchrl task envs
(``drs_torchrl.envs.variants``) draw one per episode, and this wrapper writes the index of the
episode's variant as ``"variant_index"`` (``int64``, ``(*batch, 1)``; names in ``variant_names``).
A family whose reward must not depend on the robot (``cross_robot``) also gets the task env's
robot-agnostic ``task_observation()`` under ``task_observation_key``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from drs_torchrl.envs.doctor import CudaUnavailableError, ensure_env_ready


class ManiSkillEnv(EnvBase):
    """A ManiSkill3 task as a TorchRL env (Sec. 5.1 setup: state observations, low-level control).

    Args:
        env_id: ManiSkill environment id, e.g. ``"PickCube-v1"``.
        info_keys: info entries to copy into the TensorDict (booleans), e.g. the stage indicators.
        num_envs: parallel envs (``>1`` needs the GPU backend).
        sim_backend: ``"physx_cpu"`` or ``"physx_cuda"``; ``"auto"`` picks CUDA when
            ``num_envs > 1`` and CUDA is available, else CPU.
        control_mode: ManiSkill controller (the paper uses end-effector delta position).
        reward_mode: ManiSkill reward written to ``"reward"`` (``"sparse"``, ``"normalized_dense"``...).
            Learned rewards overwrite it through a transform.
        max_episode_steps: episode length (time-limit truncation); ``None`` keeps ManiSkill's. A pooled
            env whose variants have their own limits (``variant_episode_steps``) truncates each
            episode at the smaller of the two.
        env_kwargs: extra keyword arguments for ``gym.make`` (task variant parameters).
        observation_key: where the flat state observation goes.
        task_observation_key: if set, also write the task env's ``task_observation()`` (a flat
            robot-agnostic task state, see ``envs/variants/pick.py``) under this key.
    """

    def __init__(
        self,
        env_id: str,
        info_keys: Sequence[str] = (),
        *,
        num_envs: int = 1,
        sim_backend: str = "physx_cpu",
        control_mode: str | None = "pd_ee_delta_pos",
        reward_mode: str = "sparse",
        max_episode_steps: int | None = None,
        env_kwargs: dict | None = None,
        observation_key: str = "observation",
        task_observation_key: str | None = None,
        device: str | torch.device | None = None,
        render_mode: str | None = None,
    ):
        import gymnasium as gym

        if sim_backend == "auto":
            sim_backend = "physx_cuda" if (num_envs > 1 and torch.cuda.is_available()) else "physx_cpu"
        if sim_backend not in ("physx_cpu", "physx_cuda", "cpu", "gpu", "cuda"):
            raise ValueError(f"sim_backend must be 'physx_cpu', 'physx_cuda' or 'auto', got {sim_backend!r}")
        gpu = sim_backend in ("physx_cuda", "gpu", "cuda")
        if gpu and not torch.cuda.is_available():
            raise CudaUnavailableError(
                "sim_backend='physx_cuda' was requested but CUDA is not available on this machine. "
                "Use env.sim_backend=physx_cpu (one env per process) or run on a GPU machine."
            )
        if not gpu and num_envs != 1:
            raise ValueError(
                f"The CPU backend runs one env per process (num_envs={num_envs}); use "
                "torchrl.envs.SerialEnv/ParallelEnv over several ManiSkillEnv for more CPU envs, "
                "or sim_backend=physx_cuda."
            )
        import mani_skill.envs  # noqa: F401  (registers the environments)
        import drs_torchrl.envs.variants  # noqa: F401  (registers drs-torchrl's task variants)

        ensure_env_ready(env_id, env_kwargs or {})

        kwargs = dict(env_kwargs or {})
        make_kwargs = dict(
            obs_mode="state",
            num_envs=num_envs,
            sim_backend="physx_cuda" if gpu else "physx_cpu",
            reward_mode=reward_mode,
            render_mode=render_mode,  # "rgb_array" for videos (drs-eval --video); None: no camera work
            **kwargs,
        )
        if control_mode is not None:
            make_kwargs["control_mode"] = control_mode
        if max_episode_steps is not None:
            make_kwargs["max_episode_steps"] = int(max_episode_steps)
        self._gym_env = gym.make(env_id, **make_kwargs)
        self.env_id = env_id
        self.info_keys = tuple(info_keys)
        self.num_envs = num_envs
        self.gpu = gpu
        self.observation_key = observation_key
        self.task_observation_key = task_observation_key
        self.variant_names: list[str] | None = getattr(self._gym_env.unwrapped, "variant_names", None)
        u = self._gym_env.unwrapped  # per-variant time limits: only pools whose variants carry max_steps
        self._variant_steps = u.variant_episode_steps if "max_steps" in getattr(u, "VARIANT_DEFAULTS", {}) else None
        self._sim_device = torch.device("cuda" if gpu else "cpu")
        batch = torch.Size([num_envs]) if gpu else torch.Size([])
        super().__init__(device=device if device is not None else self._sim_device, batch_size=batch)
        self._seed: int | None = None
        self._make_specs()

    def render_frame(self) -> np.ndarray:
        """The current camera image, ``(H, W, 3)`` uint8 (first env), of an env made with ``render_mode="rgb_array"``."""
        frame = self._gym_env.render()
        if frame is None:
            raise RuntimeError(f"{self.env_id} was made without render_mode='rgb_array'; it renders nothing")
        frame = frame.cpu().numpy() if isinstance(frame, torch.Tensor) else np.asarray(frame)
        return frame[0] if frame.ndim == 4 else frame

    # ------------------------------------------------------------------ specs
    @property
    def unwrapped(self):
        return self._gym_env.unwrapped

    @property
    def max_episode_steps(self) -> int:
        """The env's time limit (ManiSkill's ``TimeLimitWrapper``), ``-1`` if none; a pooled env's variants
        may end their episodes earlier (``variant_episode_steps``)."""
        env = self._gym_env
        while env is not None:
            limit = env.__dict__.get("_max_episode_steps")
            if limit is not None:
                return int(limit)
            env = env.__dict__.get("env")
        spec = self._gym_env.spec
        return int(spec.max_episode_steps) if spec is not None and spec.max_episode_steps is not None else -1

    def _make_specs(self) -> None:
        obs_space = self._gym_env.unwrapped.single_observation_space
        act_space = self._gym_env.unwrapped.single_action_space
        if not hasattr(obs_space, "shape") or obs_space.shape is None or len(obs_space.shape) != 1:
            raise TypeError(f"{self.env_id}: expected a flat state observation, got {obs_space}")
        b = self.batch_size
        obs = {self.observation_key: Unbounded(shape=(*b, *obs_space.shape), dtype=torch.float32, device=self.device)}
        # probe one reset to learn which info entries exist
        _, info = self._gym_env.reset(seed=0)
        missing = [k for k in self.info_keys if k not in info]
        if missing:
            raise KeyError(
                f"{self.env_id} does not report info entries {missing}; it reports "
                f"{sorted(k for k in info if k not in ('reconfigure', 'elapsed_steps'))}. "
                "Fix the task family's indicator keys."
            )
        for k in self.info_keys:
            obs[k] = Categorical(2, shape=(*b, 1), dtype=torch.bool, device=self.device)
        if self.variant_names:
            obs["variant_index"] = Categorical(
                len(self.variant_names), shape=(*b, 1), dtype=torch.int64, device=self.device
            )
        if self.task_observation_key:
            task_obs = getattr(self._gym_env.unwrapped, "task_observation", None)
            if task_obs is None:
                raise TypeError(
                    f"{self.env_id} has no task_observation(); task_observation_key needs one of drs-torchrl's task envs"
                )
            obs[self.task_observation_key] = Unbounded(
                shape=(*b, task_obs().shape[-1]), dtype=torch.float32, device=self.device
            )
        self.observation_spec = Composite(obs, shape=b, device=self.device)
        self.action_spec = Bounded(
            low=torch.tensor(np.broadcast_to(act_space.low, act_space.shape), dtype=torch.float32),
            high=torch.tensor(np.broadcast_to(act_space.high, act_space.shape), dtype=torch.float32),
            shape=(*b, *act_space.shape),
            dtype=torch.float32,
            device=self.device,
        )
        self.reward_spec = Unbounded(shape=(*b, 1), dtype=torch.float32, device=self.device)
        self.done_spec = Composite(
            done=Categorical(2, shape=(*b, 1), dtype=torch.bool, device=self.device),
            terminated=Categorical(2, shape=(*b, 1), dtype=torch.bool, device=self.device),
            truncated=Categorical(2, shape=(*b, 1), dtype=torch.bool, device=self.device),
            shape=b,
            device=self.device,
        )

    # ---------------------------------------------------------------- helpers
    def _shape(self, x: torch.Tensor, trailing: int) -> torch.Tensor:
        """ManiSkill always returns a leading env dim; drop it for the CPU (unbatched) case."""
        x = torch.as_tensor(x)
        if not self.gpu:
            x = x.reshape(x.shape[1:]) if x.ndim > trailing else x
        return x.to(self.device)

    def _info_td(self, info: dict, out: dict) -> None:
        for k in self.info_keys:
            v = torch.as_tensor(info[k]).to(torch.bool).reshape(*self.batch_size, 1)
            out[k] = v.to(self.device)
        u = self._gym_env.unwrapped
        if self.variant_names:
            out["variant_index"] = (
                u.variant_index.to(torch.int64).reshape(*self.batch_size, 1).to(self.device, copy=True)
            )
        if self.task_observation_key:
            out[self.task_observation_key] = (
                u.task_observation().to(torch.float32).reshape(*self.batch_size, -1).to(self.device)
            )

    # ------------------------------------------------------------------ API
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        options = {}
        if self.gpu and tensordict is not None and "_reset" in tensordict.keys():
            idx = tensordict["_reset"].reshape(-1).nonzero().squeeze(-1)
            if idx.numel() < self.num_envs:
                options["env_idx"] = idx.to(self._sim_device)
        seed, self._seed = self._seed, None
        obs, info = self._gym_env.reset(seed=seed, options=options or None)
        out = {self.observation_key: self._shape(obs, 1).to(torch.float32)}
        self._info_td(info, out)
        false = torch.zeros((*self.batch_size, 1), dtype=torch.bool, device=self.device)
        out.update(done=false, terminated=false.clone(), truncated=false.clone())
        return TensorDict(out, batch_size=self.batch_size, device=self.device)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict["action"].detach().to(self._sim_device)  # a rollout outside no_grad hands over a graph
        if not self.gpu:
            action = action.unsqueeze(0)
        obs, reward, terminated, truncated, info = self._gym_env.step(action)
        b = self.batch_size
        terminated = torch.as_tensor(terminated).to(torch.bool).reshape(*b, 1).to(self.device)
        truncated = torch.as_tensor(truncated).to(torch.bool).reshape(*b, 1).to(self.device)
        if self._variant_steps is not None:  # variants with their own time limits (pooled envs)
            limit = self._variant_steps()
            if limit is not None:
                over = self._gym_env.unwrapped.elapsed_steps.to(limit.device) >= limit
                truncated = truncated | over.reshape(*b, 1).to(self.device)
        out = {
            self.observation_key: self._shape(obs, 1).to(torch.float32),
            "reward": torch.as_tensor(reward).to(torch.float32).reshape(*b, 1).to(self.device),
            "terminated": terminated,
            "truncated": truncated,
            "done": terminated | truncated,
        }
        self._info_td(info, out)
        return TensorDict(out, batch_size=b, device=self.device)

    def _set_seed(self, seed: int | None) -> None:
        # ManiSkill seeds its episode RNG on the next reset; torch's global RNG is left alone
        self._seed = None if seed is None else int(seed)

    def close(self, *, raise_if_closed: bool = True):
        try:
            self._gym_env.close()
        finally:
            super().close(raise_if_closed=raise_if_closed)
