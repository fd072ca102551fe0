"""A drs-learn / drs-reuse run built from its Hydra config: the pieces the loop of Algorithm 1 receives.

:class:`Run` builds, in order: the reward slot (a frozen reward in the env, or a learner for phase 1), the task
family's envs, the demonstrations, the reward learner, the algorithm's updater (``algo.updater``: SAC, PPO, ...),
the checkpointer and the logger; :meth:`Run.run` builds the collector for the remaining budget and hands it all
to :func:`drs_torchrl.loop.run_algorithm1`.
"""

from __future__ import annotations

import functools
import json
import random
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from hydra.utils import get_class, instantiate
from omegaconf import DictConfig, OmegaConf, open_dict
from torchrl.collectors import AsyncCollector
from torchrl.envs.utils import ExplorationType, set_exploration_type
from tqdm.auto import tqdm

from drs_torchrl.runtime.checkpoint import (
    Checkpointer,
    atomic_write_text,
    find_training_state,
)
from drs_torchrl.data.demo_mix import demo_replay_buffer, plan_demo_use, requested_sac_share
from drs_torchrl.demos.store import demos_for_run
from drs_torchrl.envs.factory import make_family_env
from drs_torchrl.runtime.errors import ConfigError
from drs_torchrl.loop import EpisodeWindow, Progress, Schedule, aggregate_episodes, episode_summary, run_algorithm1
from drs_torchrl.models import POLICY_FORMAT, read_policy_checkpoint
from drs_torchrl.precision import describe_precision, grad_scaler, resolve_precision
from drs_torchrl.runtime.provenance import code_version
from drs_torchrl.rewards import is_learned, reused_reward_settings, reward_setup, stage_buffers_hold_demos
from drs_torchrl.runtime.signals import worker_env
from drs_torchrl.tasks import TASK_OBSERVATION_KEY, family_from_config
from drs_torchrl.apps.factories import (
    make_collector,
    make_envs,
    make_logger,
    make_replay_buffer,
    make_reward_learner,
    variant_overrides,
)
from drs_torchrl.apps.validation import collector_for_device, collects_in_background, validate_config
from drs_torchrl.transforms.classifier_reward import ClassifierReward
from drs_torchrl.updaters.base import backward_and_step


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def _resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def save_config(cfg: DictConfig, path: Path, resolved: dict[str, Any] | None = None) -> None:
    """The run's config with the values it ``resolved`` (dotted keys: an ``auto`` setting's choice, a reused reward's
    settings), so that a resume on another machine runs as this run did; interpolations resolved, except
    ``algo.updater`` and a learned reward's ``reward.model`` / ``reward.learner``: those nodes only wire the settings
    into their builders (``${..gamma}``, ``${..disc.lr}``, ...), so they are kept as links and a config edited later (or a resume that changes a setting) builds the updater from the
    settings as they are, not from a stale copy."""
    data = OmegaConf.create(OmegaConf.to_container(cfg, resolve=True))
    with open_dict(data):
        for key, value in (resolved or {}).items():
            OmegaConf.update(data, key, value, merge=False, force_add=True)
    data = OmegaConf.to_container(data)
    data["algo"]["updater"] = OmegaConf.to_container(cfg.algo.updater, resolve=False)
    for key in ("model", "learner"):  # a learned reward's builders: links to the reward's settings, as the updater's
        if cfg.reward.get(key) is not None:
            data["reward"][key] = OmegaConf.to_container(cfg.reward[key], resolve=False)
    OmegaConf.save(OmegaConf.create(data), path)


class Run:
    """The built pieces of one drs-learn / drs-reuse run (``resume=True``: restored from its training state)."""

    def __init__(self, cfg: DictConfig, phase: str, run_dir: str | Path, *, resume: bool = False):
        self.env = self.eval_env = self.collector = self.logger = None
        self.training = False  # from the first env step on, a KeyError or ValueError is a bug, not a setting
        try:
            validate_config(cfg, phase, resume)
            self.cfg, self.phase, self.run_dir = cfg, phase, Path(run_dir)
            self.run_dir.mkdir(parents=True, exist_ok=True)
            if resume:
                find_training_state(self.run_dir)  # fail before building anything
            seed_everything(int(cfg.seed))
            if cfg.get("torch_threads"):
                torch.set_num_threads(int(cfg.torch_threads))
            self.device = device = _resolve_device(str(cfg.device))
            # what this run resolves (auto settings, a reused reward's settings), by dotted key: computed once here and
            # recorded once, in config.yaml, so that a resume on another machine runs as this run did; the composed
            # config itself is not written to (self.setting reads the two together)
            self.resolved: dict[str, Any] = {}
            # algo.precision: autocast of the learner's forward passes, fp32 master weights (drs_torchrl.precision)
            self.precision = resolve_precision(str(cfg.algo.get("precision") or "fp32"), device)
            if cfg.algo.get("precision") == "auto":
                self.resolved["algo.precision"] = self.precision
            scaler = grad_scaler(self.precision, device)
            self.collector_cfg, note = collector_for_device(cfg.algo.collector, device)
            self.notes = [note] if note else []  # printed when the run starts
            if note:
                self.resolved["algo.collector"] = OmegaConf.to_container(self.collector_cfg)

            # the reward slot: static rewards and frozen learned ones are env transforms; phase 1 builds a learner
            self.reward = reward = reward_setup(cfg.reward, phase)
            frozen, notes = reused_reward_settings(
                cfg.reward, reward.frozen
            )  # a reused reward is used as it was learned
            self.notes += notes
            self.resolved.update({f"reward.{k}": v for k, v in frozen.items()})
            reads = list(self.setting("reward.in_keys") or getattr(reward.frozen, "reward_in_keys", None) or ())
            if TASK_OBSERVATION_KEY in reads and not cfg.env.get("task_observation"):
                self.resolved["env.task_observation"] = True  # the reward reads the task state: the env writes it
            self.family = family = family_from_config(cfg.env, task_observation=self.setting("env.task_observation"))
            self.env, self.eval_env, self._env_kwargs = make_envs(
                cfg.env, family, reward, device, seed=int(cfg.seed), eval_split=cfg.eval.get("split")
            )

            # phase 1 of a learned reward: the demonstrations, how they are used, and the reward learner
            learns = phase == "learn" and is_learned(cfg.reward)
            demos_cfg = cfg.get("demos") or {}
            # a resumed DrS run has its demonstrations in its stage-buffer snapshot (the file is read again only for
            # demos.sac_share); the classifiers keep theirs apart from their data and read the file again
            in_stage_buffers = learns and stage_buffers_hold_demos(cfg.reward)
            in_state = resume and in_stage_buffers
            reread = not in_state or requested_sac_share(demos_cfg.get("sac_share")) != 0
            demos = self._demonstrations(demos_cfg) if learns and reread else None
            use = plan_demo_use(
                demos,
                stage_buffers=demos_cfg.get("stage_buffers", True),
                sac_share=demos_cfg.get("sac_share"),
                path=demos_cfg.get("path"),
                files_in_stage_buffers=in_stage_buffers,
                learned=learns,
                action_dim=int(self.env.action_spec.shape[-1]),
                control_mode=self._control_mode(cfg),
                root_keys=list(cfg.algo.policy_in_keys),
            )
            self.resolved.update(use.resolved)
            for note in use.notes:
                tqdm.write(f"drs-{phase}: {note}")
            self.learner = None
            if learns:
                self.learner = make_reward_learner(
                    cfg.reward,
                    family,
                    self.env,
                    split=cfg.env.split,
                    variant_overrides=variant_overrides(cfg.env),
                    seed=int(cfg.seed),
                    reward_updates_per_update=float(cfg.algo.get("reward_updates_per_update") or 1),
                    device=device,
                    precision=self.precision,
                    step_fn=functools.partial(backward_and_step, scaler),
                    demos=demos if use.stage_buffers and not in_state else None,
                )
                reward.learned = self.learner.reward
            self.learned = reward.learned
            formula = getattr(self.learned if self.learned is not None else reward.frozen, "formula", None)
            if formula in ("paper", "sum") and family.backend == "maniskill":
                self.notes.append(
                    f"reward.formula={formula} gives rewards near or above 0 while a ManiSkill episode ends on success, "
                    "so an agent may earn more by staying just short of success; formula=rescaled (the default, the "
                    "authors' code) keeps every reward below 0"
                )

            # the algorithm: an off-policy one samples a replay buffer whose transform recomputes the learned reward
            # (Algorithm 1, line 18), with the demonstrations' share of each batch (demos.sac_share)
            demo_replay, demo_batch = None, 0
            if use.sac_share > 0:
                demo_replay = demo_replay_buffer(demos, list(cfg.algo.policy_in_keys), self.learned, device)
                demo_batch = max(1, round(use.sac_share * int(cfg.algo.batch_size)))
            replay = None
            if cfg.algo.get("replay_buffer") is not None:
                replay = make_replay_buffer(
                    cfg.algo.replay_buffer, self.learned, device, int(cfg.algo.batch_size) - demo_batch
                )
                if self.learner is not None:
                    self.learner.attach(replay)  # GAIL draws the agent's transitions from it
            self.updater = instantiate(cfg.algo.updater)(  # e.g. updaters.sac.make_sac_updater (conf/algo/)
                self.env,
                replay,
                device=device,
                precision=self.precision,
                grad_scaler=scaler,
                demo_replay=demo_replay,
                demo_batch=demo_batch,
                reward=self.learned,
            )
            self.actor = self.updater.eval_policy
            if cfg.get("init_from") and not resume:  # Sec. 5.4.2: fine-tune a phase-1 agent instead of a fresh one
                self._init_from(cfg.init_from)

            self.checkpointer = Checkpointer(self.run_dir, self.updater.buffers, self.learner)
            self.progress = Progress()
            self.episodes = EpisodeWindow(int(cfg.logger.episode_window), family.num_stages, self.episode_reward)
            if resume:
                self.load_training_state()
                self.env.set_seed(int(cfg.seed) + 1 + self.frames)  # fresh episodes, not the first run's
            self._segment_from, self._segment_start = self.frames, time.perf_counter()  # this process's part of the run
            self.logger = make_logger(cfg.logger, self.run_dir, resume_step=self.progress.resumed_from)
            # written last: a run that fails to start (or to resume) leaves the directory as it was
            save_config(cfg, self.run_dir / "config.yaml", self.resolved)
        except BaseException:  # what was built (envs, a logger) is closed; the run directory is as it was
            self.close()
            raise

    def setting(self, key: str, default: Any = None) -> Any:
        """A setting as this run uses it: what the run resolved (:attr:`resolved`), else the composed config's."""
        if key in self.resolved:
            return self.resolved[key]
        return OmegaConf.select(self.cfg, key, default=default)

    @property
    def frames(self) -> int:
        return self.progress.frames

    # ------------------------------------------------------------------ rewards
    def episode_reward(self, episode) -> torch.Tensor:
        """Reward of an episode's transitions under the reward being trained on (for logging)."""
        if self.learned is None:
            return episode.get(("next", "reward"))
        episode = episode.to(self.device)
        # DrS reads next states; a classifier reward may read (s, a) and takes whole transitions
        return self.learned.reward(episode if isinstance(self.learned, ClassifierReward) else episode.get("next"))

    # ------------------------------------------------------------------ demonstrations
    def _demonstrations(self, demos_cfg) -> list | None:
        """The episodes of ``demos.path`` (``demos.num`` of them), checked against this task, or None."""
        if not demos_cfg.get("path"):
            return None
        cfg, spec = self.cfg, self.env.observation_spec
        in_keys = list(cfg.reward.get("in_keys") or self.family.reward_in_keys)
        overrides = cfg.env.get("variant_overrides")
        episodes, warnings = demos_for_run(
            demos_cfg["path"],
            self.family,
            num=demos_cfg.get("num"),
            in_sizes={k: int(spec[k].shape[-1]) for k in in_keys if k in spec.keys(True, True)},
            variant_overrides=OmegaConf.to_container(overrides) if overrides else None,
            reward_name=str(cfg.reward.name),
            use_action=bool(cfg.reward.get("use_action")),
            action_size=int(self.env.action_spec.shape[-1]),
            control_mode=self._control_mode(cfg),
        )
        for warning in warnings:
            tqdm.write(f"drs-{self.phase}: warning: {warning}")
        return episodes

    def _control_mode(self, cfg) -> str:
        """The controller this run's agent acts with (env.control_mode, else its split's, else the family's)."""
        return (
            cfg.env.control_mode or self.family.env_args(cfg.env.split).get("control_mode") or self.family.control_mode
        )

    def _init_from(self, run_dir) -> None:
        """Start from another run's ``checkpoints/policy.pt`` (fine-tuning, Sec. 5.4.2); optimisers and replay
        start fresh."""
        file, ck = read_policy_checkpoint(run_dir)
        if ck.get("family") != self.family.name:
            problems = [f"it is a policy for family {ck.get('family')!r}, this run is {self.family.name!r}"]
        elif not hasattr(self.updater, "init_from"):
            problems = [f"algo updater {self.updater.name} cannot start from a policy checkpoint"]
        else:
            problems = self.updater.init_from(ck)
        if problems:
            raise ConfigError(f"init_from={run_dir}: cannot fine-tune from {file}: " + "; ".join(problems))
        self.init_from = str(file)

    # --------------------------------------------------------------- evaluation
    def evaluate(self) -> dict[str, float]:
        """``eval.episodes`` deterministic episodes on the evaluation split (the same ones each time with
        ``eval.episode_seed``): success rate, per-stage reach rates, length, return."""
        n = int(self.cfg.eval.episodes)
        if n == 0:
            return {}
        episodes, first_seed = [], self.cfg.eval.get("episode_seed")
        with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
            for j in range(n):
                if first_seed is not None:  # a seeded reset: the same n episodes at every evaluation, in every run
                    self.eval_env.set_seed(int(first_seed) + j, static_seed=True)
                ep = self.eval_env.rollout(10_000, self.updater.eval_policy, break_when_any_done=True)
                while ep.batch_dims > 1:  # a GPU env with num_envs=1 has batch (1, T)
                    ep = ep[0]
                episodes.append(episode_summary(ep, self.episode_reward))
        return aggregate_episodes(episodes, self.family.num_stages)

    # -------------------------------------------------------------- checkpoints
    def _policy_file(self) -> dict[str, Any]:
        return {
            "format": POLICY_FORMAT,
            "version": 1,
            "frames": self.frames,
            "family": self.family.name,
            "algo": self.updater.name,
            **self.updater.policy_checkpoint(),
        }

    def save_checkpoints(self) -> dict[str, str]:
        """The user-facing checkpoints: the learned reward (phase 1) and the policy."""
        ck, policy = self.checkpointer.dir, self._policy_file()
        reward = [self.learner.reward.state_dict()] if self.learner is not None else []
        self.checkpointer.check_room([policy, *reward], self._state_payload())
        paths = {}
        if self.learner is not None:
            paths["reward"] = str(self.learner.save_reward(ck / "reward.pt", frames=self.frames, phase=self.phase))
        paths.update(self.checkpointer.save_files({"policy": policy}))
        return paths

    def save_training_state(self) -> Path:
        """Everything needed to continue the run (:class:`~drs_torchrl.runtime.checkpoint.Checkpointer`)."""
        return self.checkpointer.save_state(self._state_payload())

    def _save(self) -> dict[str, str]:
        paths = self.save_checkpoints()
        self.save_training_state()
        return paths

    def _state_payload(self) -> dict:
        """The training state apart from the buffers (``trainer.pt``), with this run's processes so far."""
        return self.checkpointer.loop_state(
            self.phase, self.updater, self.progress, self.episodes, segments=self.segments()
        )

    def segments(self) -> list[dict]:
        """The run's processes so far: the earlier ones (from the training state) and this one, up to now."""
        now = {
            "from": self._segment_from,
            "to": self.frames,
            "wall_s": round(time.perf_counter() - self._segment_start, 1),
        }
        return [*self.progress.segments, now]

    def load_training_state(self) -> None:
        counters = self.checkpointer.restore_loop_state(self.phase, self.updater, self.progress, self.episodes)
        self.progress.segments = list(counters.get("segments", []))  # states written before segments were kept: none

    # --------------------------------------------------------------------- run
    @property
    def collects_in_background(self) -> bool:
        """True when the configured collector steps the env in its own process (``collects_in_background``)."""
        return collects_in_background(self.collector_cfg)

    def _collector_env(self):
        """The env for the collector: the run's own env for an in-process collector, else a picklable
        constructor of the same env (same transforms: stage labelling, a frozen reward in phase 2), seeded like
        the run's (``seed``; ``seed + 1 + frames`` on resume), which the collector's worker process calls."""
        if not self.collects_in_background:
            return self.env
        seed = int(self.cfg.seed) + (1 + self.frames if self.progress.resumed_from is not None else 0)
        transforms = (self.reward.frozen.clone(),) if self.reward.frozen is not None else ()

        def factory(worker: int):
            make = functools.partial(
                make_family_env,
                self.family,
                self.cfg.env.split,
                seed=seed + 7919 * worker,
                transforms=transforms,
                **self._env_kwargs,
            )
            return functools.partial(worker_env, make)

        if issubclass(get_class(self.collector_cfg._target_), AsyncCollector):
            return factory(0)
        # MultiAsyncCollector / MultiSyncCollector: one differently seeded env per worker process
        return [factory(w) for w in range(int(self.collector_cfg.get("num_workers") or 1))]

    def make_collector(self, frames: int):
        """The configured TorchRL collector for the next ``frames`` env steps, acting with the updater's policy
        (random actions until ``algo.learning_starts``)."""
        return make_collector(
            self.collector_cfg,
            self._collector_env(),
            self.updater.policy,
            frames,
            learning_starts=int(self.cfg.algo.learning_starts),
            frames_done=self.frames,
            device=self.device,
        )

    def run(self) -> dict[str, Any]:
        """Algorithm 1 from where the run stands to ``total_frames`` env steps; writes and returns the summary."""
        cfg = self.cfg
        summary: dict[str, Any] = {
            "phase": self.phase,
            "run_dir": str(self.run_dir),
            "resumed_from": self.progress.resumed_from,
            "algo": self.updater.name,
            "precision": self.precision,
            "init_from": cfg.get("init_from"),
            "code": code_version(),
        }
        tqdm.write(f"drs-{self.phase}: {describe_precision(self.precision, self.device)}")
        for note in self.notes:
            tqdm.write(f"drs-{self.phase}: {note}")
        try:
            if self.learner is not None and self.frames == 0 and self.progress.resumed_from is None:
                self.learner.prepare(self.env)  # e.g. ORIL's offline classifier, before the first env step
            remaining = int(cfg.total_frames) - self.frames
            if remaining > 0:
                self.collector = self.make_collector(remaining)
                if self.collects_in_background and not self.env.is_closed:
                    self.env.close()  # its specs were all the run needed; the worker has its own simulator
            background = self.collector is not None and self.collects_in_background
            self.training = True
            summary.update(
                run_algorithm1(
                    self.collector if self.collector is not None else (),
                    self.updater,
                    learner=self.learner,
                    episodes=self.episodes,
                    logger=self.logger,
                    evaluate=self.evaluate,
                    save=self._save,
                    schedule=Schedule(
                        total_frames=int(cfg.total_frames),
                        log_interval=int(cfg.logger.interval),
                        eval_interval=int(cfg.eval.interval),
                        checkpoint_interval=int(cfg.checkpoint_interval),
                        stop_at_success=cfg.get("stop_at_success"),
                        stop_at_eval_success=cfg.eval.get("stop_at_success"),
                        stop_streak=int(cfg.eval.get("stop_streak") or 1),
                    ),
                    progress=self.progress,
                    sync_policy=self.collector.update_policy_weights_ if background else None,
                    name=f"drs-{self.phase}",
                    progress_bar=bool(cfg.logger.progress_bar),
                    where=str(self.checkpointer.dir),
                )
            )
            segments = self.segments()  # every process of the run: where each started and ended, its wall time
            summary.update(
                segments=segments,
                env_steps_per_s_overall=round(
                    sum(g["to"] - g["from"] for g in segments) / max(sum(g["wall_s"] for g in segments), 1e-9), 1
                ),
            )
            atomic_write_text(self.run_dir / "summary.json", json.dumps(summary, indent=2))
        finally:
            self.close()  # the collector's worker must not outlive the run (NaN, a full disk, ...)
        return summary

    def close(self) -> None:
        if self.logger is not None:
            self.logger.close()
            self.logger = None
        if self.collector is not None:
            try:
                self.collector.shutdown()
            except Exception:
                pass
            self.collector = None  # freed now, not at interpreter exit
        for env in (self.env, self.eval_env):
            if env is not None and not env.is_closed:
                env.close()


def train(cfg: DictConfig, phase: str, run_dir: str | Path, *, resume: bool = False) -> dict[str, Any]:
    """Run (or, with ``resume=True``, continue) one phase with the Hydra config ``cfg``."""
    return Run(cfg, phase, run_dir, resume=resume).run()
