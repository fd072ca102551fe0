"""The DrS training loop (Algorithm 1): phase 1 (reward learning) and phase 2 (reward reuse).

Both phases are the same off-policy SAC loop; phase 1 adds the stage buffers and the
discriminator updates, and the reward is recomputed from the current discriminators each time SAC
samples. In phase 2 (and for the baselines) the reward sits frozen in the env.

``train(cfg, phase)`` wires TorchRL pieces built from the Hydra config; the pieces themselves live in
their own modules and are usable without it.
"""

from __future__ import annotations

import functools
import json
import os
import random
import shutil
import signal
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np
import torch
from hydra.utils import get_class
from omegaconf import DictConfig, OmegaConf, open_dict
from tensordict import TensorDict
from torchrl import timeit
from torchrl.collectors import AsyncCollector, MultiCollector
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.envs.utils import ExplorationType, set_exploration_type
from tqdm.auto import tqdm

from drs_torchrl.console import UserError
from drs_torchrl.data import TrajectoryAssembler
from drs_torchrl.data.persistence import SnapshotError, buffer_bytes, dump_buffer, load_buffer
from drs_torchrl.demos import check_demos, load_demos, restage_demos, variant_mismatches
from drs_torchrl.envs.factory import make_family_env
from drs_torchrl.models import POLICY_FORMAT, POLICY_INTERMEDIATE_KEYS, read_policy_checkpoint
from drs_torchrl.provenance import code_version
from drs_torchrl.precision import autocast, describe_precision, grad_scaler, resolve_precision
from drs_torchrl.rewards import LEARNED, reward_setup
from drs_torchrl.transforms.classifier_reward import ClassifierReward
from drs_torchrl.run_logger import RunLogger
from drs_torchrl.rundir import ensure_free, nbytes, space_errors
from drs_torchrl.trainers.factories import (
    make_collector,
    make_envs,
    make_loss_module,
    make_optimizers,
    make_replay_buffer,
    make_reward_learner,
    make_sac_agent,
)
from drs_torchrl.tasks import TASK_OBSERVATION_KEY, family_from_config


class ConfigError(UserError, ValueError):
    """A configuration value that cannot work, with the fix in its message."""


# demos.sac_share=auto (the default): this share of every SAC batch from the demonstrations where they carry
# the agent's actions; the best of issue 12's phase-1 comparison on pick_cube (results/demos_compare/pick_cube/)
AUTO_SAC_SHARE = 0.25


def requested_sac_share(cfg: DictConfig) -> float | None:
    """``demos.sac_share`` as asked: a number in [0, 1), or None for ``auto``."""
    raw = (cfg.get("demos") or {}).get("sac_share")
    if raw is None:
        return 0.0
    if isinstance(raw, str) and raw.strip().lower() == "auto":
        return None
    if isinstance(raw, bool) or not isinstance(raw, (int, float)):
        raise ConfigError(f"demos.sac_share must be auto or a number in [0, 1), got {raw!r}; e.g. demos.sac_share=0.25")
    if not 0 <= float(raw) < 1:
        raise ConfigError(f"demos.sac_share must be in [0, 1), got {raw}")
    return float(raw)


# numeric settings and their types: a value of another type (``total_frames=abc``) is refused by name
# before anything compares or computes with it
_NUMERIC = {
    "total_frames": int,
    "seed": int,
    "checkpoint_interval": int,
    "torch_threads": (int, type(None)),
    "eval.interval": int,
    "eval.episodes": int,
    "eval.episode_seed": (int, type(None)),
    "logger.interval": int,
    "logger.episode_window": int,
    "algo.batch_size": int,
    "algo.frames_per_batch": int,
    "algo.learning_starts": int,
    "algo.buffer_size": int,
    "algo.utd": (int, float),
    "algo.gamma": (int, float),
    "algo.tau": (int, float),
    "reward.alpha": (int, float),
    "reward.stage_buffer_size": int,
    "reward.disc.batch_size": int,
    "reward.disc.lr": (int, float),
    "reward.disc.updates_per_sac_update": (int, float),
    "reward.disc.window": int,
    "reward.disc.early_stop_threshold": (int, float, type(None)),
}


def _check_types(cfg: DictConfig) -> None:
    for key, types in _NUMERIC.items():
        value = OmegaConf.select(cfg, key, default="__absent__")
        if isinstance(value, str) and value == "__absent__":
            continue
        if isinstance(value, bool) or not isinstance(value, types):
            kinds = types if isinstance(types, tuple) else (types,)
            want = " or ".join(
                "null" if t is type(None) else ("a number" if t is float else "an integer")
                for t in kinds
                if not (t is int and float in kinds)
            )
            raise ConfigError(
                f"{key} must be {want}, got {value!r} ({type(value).__name__}); e.g. {key}={_EXAMPLES.get(key, 1)}"
            )


_EXAMPLES = {
    "total_frames": 200000,
    "algo.gamma": 0.8,
    "algo.tau": 0.005,
    "algo.utd": 0.5,
    "reward.alpha": 0.3333,
    "reward.disc.lr": 0.0003,
    "algo.batch_size": 256,
    "seed": 0,
}


def collects_in_background(cfg: DictConfig) -> bool:
    """True when ``algo.collector`` steps the env in its own process (TorchRL's ``AsyncCollector``/
    ``MultiAsyncCollector``/``MultiSyncCollector``), overlapping simulation with the updates of this process."""
    return issubclass(get_class(cfg.algo.collector._target_), MultiCollector)


def collector_for_device(cfg: DictConfig, device: torch.device) -> str | None:
    """On a GPU, replace a background collector (``AsyncCollector``/``Multi*``: the CPU-machine speed choice of
    ``algo=sac_cpu``, whose worker cannot feed a CUDA learner) by the in-process ``Collector``; returns the
    console note, or None when nothing changed. Edits ``cfg`` (saved in config.yaml: a resume keeps it)."""
    target = cfg.algo.collector._target_
    if torch.device(device).type == "cpu" or not collects_in_background(cfg):
        return None
    with open_dict(cfg):
        cfg.algo.collector._target_ = "torchrl.collectors.Collector"
        cfg.algo.collector.pop("num_workers", None)
    return (
        f"device={torch.device(device).type}: the in-process torchrl.collectors.Collector replaces "
        f"algo.collector={target} (a background worker cannot feed a GPU learner)"
    )


def validate_config(cfg: DictConfig, phase: str) -> None:
    """Reject values that would fail later or silently do nothing."""
    _check_types(cfg)
    a = cfg.algo
    checks = [
        (cfg.total_frames > 0, f"total_frames must be > 0, got {cfg.total_frames}"),
        (a.batch_size > 0, f"algo.batch_size must be > 0, got {a.batch_size}"),
        (a.frames_per_batch > 0, f"algo.frames_per_batch must be > 0, got {a.frames_per_batch}"),
        (a.utd > 0, f"algo.utd must be > 0, got {a.utd}"),
        (0 < a.gamma <= 1, f"algo.gamma must be in (0, 1], got {a.gamma}"),
        (a.learning_starts >= 0, f"algo.learning_starts must be >= 0, got {a.learning_starts}"),
        (
            a.buffer_size >= a.batch_size,
            f"algo.buffer_size ({a.buffer_size}) is smaller than algo.batch_size ({a.batch_size})",
        ),
        (cfg.eval.episodes >= 0 and cfg.eval.interval > 0, "eval.episodes must be >= 0 and eval.interval > 0"),
        (
            cfg.eval.get("episode_seed") is None or cfg.eval.episode_seed >= 0,
            f"eval.episode_seed must be null or >= 0, got {cfg.eval.get('episode_seed')}",
        ),
        (phase in ("learn", "reuse"), f"phase must be learn or reuse, got {phase}"),
    ]
    if phase == "learn" and cfg.reward.name in LEARNED:
        checks.append((cfg.reward.disc.batch_size > 0, "reward.disc.batch_size must be > 0"))
        checks.append(
            (
                cfg.reward.disc.updates_per_sac_update > 0,
                f"reward.disc.updates_per_sac_update must be > 0 (fractions allowed, e.g. 0.5), got {cfg.reward.disc.updates_per_sac_update}",
            )
        )
    for ok, msg in checks:
        if not ok:
            raise ConfigError(msg)
    requested_sac_share(cfg)
    stage_buffers = (cfg.get("demos") or {}).get("stage_buffers", True)
    if stage_buffers not in (True, False, "auto"):
        raise ConfigError(f"demos.stage_buffers must be true, false or auto, got {stage_buffers!r}")
    if stage_buffers is False and (phase != "learn" or cfg.reward.name != "drs"):
        raise ConfigError(
            "demos.stage_buffers=false is for drs-learn reward=drs (the demonstrations in the SAC batch "
            f"only); this run is drs-{phase} reward={cfg.reward.name}"
        )
    stop = cfg.get("stop_at_success")
    if stop is not None and (isinstance(stop, bool) or not isinstance(stop, (int, float)) or not 0 <= stop <= 1):
        raise ConfigError(
            f"stop_at_success must be null or a success rate in [0, 1], got {stop!r}; e.g. stop_at_success=0.8"
        )
    if cfg.logger.get("wandb", False):
        import importlib.util

        if importlib.util.find_spec("wandb") is None:
            raise ConfigError(
                "logger.wandb=true needs the wandb package: pip install wandb (or set logger.wandb=false)"
            )
        if cfg.logger.get("wandb_mode", "offline") not in ("offline", "online"):
            raise ConfigError(f"logger.wandb_mode must be offline or online, got {cfg.logger.wandb_mode!r}")
    if cfg.device not in ("cpu", "auto") and not str(cfg.device).startswith("cuda"):
        raise ConfigError(f"device must be cpu, cuda[:i] or auto, got {cfg.device}")
    if str(cfg.device).startswith("cuda") and not torch.cuda.is_available():
        raise ConfigError(f"device={cfg.device} was requested but CUDA is not available; use device=cpu")


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def episode_summary(ep, reward_fn) -> tuple[int, bool, int, float]:
    """(highest stage, success, length, return) of one finished episode."""
    return (
        int(ep["next", "stage"].max()),
        bool(ep["next", "success"].any()),
        int(ep.shape[0]),
        float(reward_fn(ep).sum()),
    )


def aggregate_episodes(summaries, num_stages: int) -> dict[str, float]:
    """Success rate, per-stage reach rates ("reached stage >= k"), mean length and return."""
    arr = np.asarray(summaries, dtype=np.float64).reshape(-1, 4)
    out = {
        "episodes": float(arr.shape[0]),
        "success_rate": float(arr[:, 1].mean()),
        "episode_length": float(arr[:, 2].mean()),
        "episode_return": float(arr[:, 3].mean()),
    }
    for k in range(1, num_stages + 1):
        out[f"reach_stage_{k}"] = float((arr[:, 0] >= k).mean())
    return out


class Trainer:
    """Holds the TorchRL pieces of one run and runs Algorithm 1 over them."""

    def __init__(self, cfg: DictConfig, phase: str, run_dir: str | Path, *, resume: bool = False):
        self.env = self.eval_env = self.collector = self.logger = None
        try:
            self._build(cfg, phase, run_dir, resume)
        except BaseException:
            self.close()
            raise

    def _build(self, cfg: DictConfig, phase: str, run_dir: str | Path, resume: bool) -> None:
        validate_config(cfg, phase)
        self.cfg, self.phase, self.run_dir = cfg, phase, Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        (self.run_dir / "checkpoints").mkdir(exist_ok=True)
        if resume:
            find_training_state(self.run_dir)  # fail before building anything
        seed_everything(int(cfg.seed))
        if cfg.get("torch_threads"):
            torch.set_num_threads(int(cfg.torch_threads))
        self.device = torch.device(
            "cuda"
            if cfg.device == "auto" and torch.cuda.is_available()
            else ("cpu" if cfg.device == "auto" else cfg.device)
        )
        # algo.precision: autocast of the learner's forward passes, fp32 master weights (drs_torchrl.precision)
        self.precision = resolve_precision(str(cfg.algo.get("precision") or "fp32"), self.device)
        if cfg.algo.get("precision") == "auto":  # saved resolved: a resume on another machine keeps this run's numerics
            cfg.algo.precision = self.precision
        self._grad_scaler = grad_scaler(self.precision, self.device)
        note = collector_for_device(cfg, self.device)
        self.notes = [note] if note else []  # printed when the run starts
        self.reward = reward = reward_setup(cfg.reward, phase)
        reads = list(cfg.reward.get("in_keys") or getattr(reward.frozen, "reward_in_keys", None) or ())
        if TASK_OBSERVATION_KEY in reads and not cfg.env.get("task_observation"):
            with open_dict(cfg):  # the reward reads the task state: the env writes it (saved in config.yaml)
                cfg.env.task_observation = True
        self.family = family = family_from_config(cfg.env)
        self.num_stages = family.num_stages
        self.env, self.eval_env, self._env_kwargs = make_envs(cfg, family, reward, self.device)
        self.num_demos = 0
        demos = None
        self.learner = None  # the reward-learning core (drs_torchrl.learners), phase 1 of a learned reward
        if phase == "learn" and reward.name in LEARNED:
            # a resumed DrS run has its demonstrations in its stage-buffer snapshot (the file is read again only
            # for demos.sac_share); the classifiers keep theirs apart from their data and read the file again
            asked = requested_sac_share(cfg)  # a number, or None for auto
            demos = self._demonstrations(cfg, family) if (not resume or reward.name != "drs" or asked != 0) else None
            # step_fn is not a bound method: a learner -> trainer reference cycle would keep the collector (and
            # TorchRL's weight-sync scheme, whose __del__ deadlocks at interpreter exit) alive until then
            # demos.stage_buffers=false: the demonstrations feed the SAC batch only, so the discriminators'
            # positives are the agent's own successes (no "moves like the demonstrator" shortcut; results/reuse/pick_cube/)
            filed = demos if self._resolve_stage_buffers(cfg, demos, asked) else None
            self.learner = make_reward_learner(
                cfg,
                family,
                self.env,
                self.device,
                self.precision,
                functools.partial(backward_and_step, self._grad_scaler),
                demos=None if (resume and reward.name == "drs") else filed,
            )
            reward.learned = self.learner.reward
        self.learned = reward.learned

        self.actor, self.qvalue = make_sac_agent(cfg, self.env, self.device)
        self.loss, self.target_updater = make_loss_module(
            cfg, self.actor, self.qvalue, self.env.action_spec, self.device, self.precision
        )
        if cfg.get("init_from") and not resume:  # Sec. 5.4.2: fine-tune a phase-1 agent instead of a fresh one
            self._init_from(cfg.init_from)
        # algo.compile: the SAC loss's forward (and, through AOTAutograd, its backward) compiled with
        # torch.compile; the module, its parameters and checkpoints stay those of self.loss
        self._loss_fn = (
            torch.compile(self.loss, **(cfg.algo.get("compile_kwargs") or {})) if cfg.algo.get("compile") else self.loss
        )
        self.optimizers = make_optimizers(cfg, self.loss)
        self.optim_actor, self.optim_critic, self.optim_alpha = (
            self.optimizers[k] for k in ("actor", "critic", "alpha")
        )
        # the learned reward recomputes ("next", "reward") from the current discriminators at sampling
        # (its storage lives on the learner's device, where the reward transform runs)
        # (with demos.sac_share, the demonstrations' own buffer fills its share of each batch, the agent's the rest)
        self.demo_replay, self._demo_batch = self._demo_transitions(cfg, demos if self.learner is not None else None)
        if demos and (cfg.get("demos") or {}).get("stage_buffers", True) is False and self._demo_batch == 0:
            raise ConfigError(
                f"demos.stage_buffers=false keeps the demonstrations out of the stage buffers, and demos.sac_share "
                f"is {cfg.demos.sac_share}: they would not be used at all; set demos.sac_share=0.25 "
                "(demonstrations with the agent's actions: drs-demos' default) or demos.stage_buffers=true"
            )
        self.replay = make_replay_buffer(cfg, self.learned, self.device, int(cfg.algo.batch_size) - self._demo_batch)
        # the actor's intermediate outputs and the collector's bookkeeping are not stored: SACLoss
        # recomputes the former, nothing reads the latter, and every extra key costs at each sample
        self._replay_exclude = (*POLICY_INTERMEDIATE_KEYS, "collector")
        if self.learner is not None:
            self.learner.attach(self.replay)  # GAIL draws the agent's transitions from it
        self.collector = None  # built by run(): its budget depends on where the run starts
        self.assembler = TrajectoryAssembler()
        self.frames = 0
        self.updates = 0
        self._owed_updates = 0.0
        self._last_eval_frames = -1
        self.recent: deque = deque(maxlen=int(cfg.logger.episode_window))
        self.resumed_from: int | None = None
        if resume:
            self.load_training_state()
            self.resumed_from = self.frames
            self.env.set_seed(int(cfg.seed) + 1 + self.frames)  # fresh episodes, not the first run's
        self.logger = RunLogger(
            self.run_dir,
            tensorboard=cfg.logger.tensorboard,
            csv_files=cfg.logger.csv,
            resume_step=self.resumed_from,
            wandb=bool(cfg.logger.get("wandb", False)),
            wandb_project=cfg.logger.get("wandb_project", "drs-torchrl"),
            wandb_mode=cfg.logger.get("wandb_mode", "offline"),
        )
        # written last: a run that fails to start (or to resume) leaves the directory as it was
        OmegaConf.save(cfg, self.run_dir / "config.yaml", resolve=True)

    # ------------------------------------------------------------------ rewards
    def episode_reward(self, episode) -> torch.Tensor:
        """Reward of an episode's transitions under the reward being trained on (for logging)."""
        if self.learned is None:
            return episode.get(("next", "reward"))
        episode = episode.to(self.device)
        # DrS reads next states; a classifier reward may read (s, a) and takes whole transitions
        return self.learned.reward(episode if isinstance(self.learned, ClassifierReward) else episode.get("next"))

    # ------------------------------------------------------------------ updates
    @property
    def disc_updates(self) -> int:
        """Update steps the reward learner has taken (discriminators or classifier)."""
        return self.learner.updates if self.learner is not None else 0

    def _demonstrations(self, cfg, family) -> list | None:
        """The episodes of ``demos.path`` (``demos.num`` of them), checked against this task, or None."""
        demos = cfg.get("demos") or {}
        if not demos.get("path"):
            return None
        episodes, meta = load_demos(demos["path"])
        if list(meta["stage_keys"]) != list(family.stage_keys) and set(family.stage_keys) <= set(meta["stage_keys"]):
            # a stage ablation (env.stages): the demonstrations keep every indicator, so relabel them
            episodes, meta = restage_demos(episodes, meta, family.stage_keys)
        mismatched = variant_mismatches(meta, cfg.env.get("variant_overrides"))
        if mismatched:
            overrides = " ".join(
                f"--override {k}={v}" for k, v in OmegaConf.to_container(cfg.env.variant_overrides).items()
            )
            tqdm.write(
                f"drs-{self.phase}: warning: {demos['path']} were recorded without this run's env.variant_overrides "
                f"{'; '.join(mismatched)}: their stages follow the recording's task. To match, record them with "
                f"drs-demos --family {family.name} {overrides} --out NEW.demos"
            )
        in_keys = list(cfg.reward.get("in_keys") or family.reward_in_keys)
        spec = self.env.observation_spec
        check_demos(
            meta, family, {k: int(spec[k].shape[-1]) for k in in_keys if k in spec.keys(True, True)}, demos["path"]
        )
        n = len(episodes) if demos.get("num") is None else int(demos["num"])
        if n > len(episodes):
            raise ConfigError(f"demos.num={n} but {demos['path']} holds only {len(episodes)} demonstrations")
        if cfg.reward.get("use_action"):  # (s, a) rewards need the agent's own actions
            acts = meta.get("actions")
            mode = self._control_mode(cfg)
            if acts is None:
                raise ConfigError(
                    f"reward={cfg.reward.name} reads (s, a), but {demos['path']} holds states only (planner "
                    "demonstrations, or recorded before actions were kept); record demonstrations with "
                    "drs-demos --from-policy RUN_DIR, or use reward.use_action=false"
                )
            if acts["control_mode"] != mode or int(acts["size"]) != int(self.env.action_spec.shape[-1]):
                raise ConfigError(
                    f"the actions in {demos['path']} are {acts['size']}-dimensional {acts['control_mode']} "
                    f"commands; this run acts with {int(self.env.action_spec.shape[-1])}-dimensional {mode}"
                )
        self.num_demos = n
        return episodes[:n]

    def _init_from(self, run_dir) -> None:
        """Start from the actor, twin critics (and their targets) and entropy coefficient of another
        run's ``checkpoints/policy.pt`` (fine-tuning, Sec. 5.4.2); optimisers and replay start fresh."""
        file, ck = read_policy_checkpoint(run_dir)
        problems = []
        if ck.get("family") != self.family.name:
            problems.append(f"it is a policy for family {ck.get('family')!r}, this run is {self.family.name!r}")
        if list(ck["policy_in_keys"]) != list(self.cfg.algo.policy_in_keys) or list(ck["hidden"]) != list(
            self.cfg.algo.hidden
        ):
            problems.append(
                f"its networks read {ck['policy_in_keys']} with hidden {ck['hidden']}, this run's read "
                f"{list(self.cfg.algo.policy_in_keys)} with hidden {list(self.cfg.algo.hidden)}"
            )
        if "qvalue_params" not in ck:
            problems.append("it holds no critics")
        if not problems:
            try:
                self.actor.load_state_dict(ck["actor"])
                q = TensorDict(ck["qvalue_params"]).to(self.device)
                self.loss.qvalue_network_params.data.update_(q)
                self.loss.target_qvalue_network_params.data.update_(q)
                if "log_alpha" in ck:
                    self.loss.log_alpha.data.copy_(torch.as_tensor(ck["log_alpha"]))
            except (RuntimeError, KeyError) as exc:
                problems.append(f"its sizes do not fit this env: {str(exc).splitlines()[0]}")
        if problems:
            raise ConfigError(f"init_from={run_dir}: cannot fine-tune from {file}: " + "; ".join(problems))
        self.init_from = str(file)

    def _control_mode(self, cfg) -> str:
        """The controller this run's agent acts with (env.control_mode, else its split's, else the family's)."""
        return (
            cfg.env.control_mode or self.family.env_args(cfg.env.split).get("control_mode") or self.family.control_mode
        )

    def _resolve_stage_buffers(self, cfg, demos, asked) -> bool:
        """``demos.stage_buffers``: true / false as asked; ``auto`` (the default recipe, docs/recipe.md) keeps
        DrS's demonstrations out of the stage buffers when they can feed the SAC batch (they carry the agent's
        actions and ``demos.sac_share`` is not 0), so the positives are the agent's own successes; saved resolved."""
        want = (cfg.get("demos") or {}).get("stage_buffers", True)
        if want != "auto":
            return bool(want)
        sac_only = (
            bool(demos)
            and self.reward.name == "drs"
            and asked != 0
            and "action" in demos[0].keys()
            and "state" in demos[0].keys()
            and int(demos[0]["action"].shape[-1]) == int(self.env.action_spec.shape[-1])
        )
        if demos:
            tqdm.write(
                f"drs-{self.phase}: demos.stage_buffers=auto -> {str(not sac_only).lower()}: "
                + (
                    "the demonstrations feed the SAC batch only; the discriminators' positives are the agent's own successes"
                    if sac_only
                    else "the demonstrations go into the top stage buffer (the paper's Algorithm 1, line 3)"
                )
            )
        with open_dict(cfg):
            cfg.demos.stage_buffers = not sac_only
        return not sac_only

    def _sac_share_problems(self, cfg, demos) -> list[str]:
        """Why the demonstrations cannot fill a share of the SAC batch (empty when they can)."""
        if self.learner is None or not demos:
            return [
                "demos.sac_share needs demonstrations (demos.path) and a reward learned in this run "
                "(drs-learn reward=drs|vice_raq|oril|gail), which rewards them at sampling"
            ]
        if "action" not in demos[0].keys() or "state" not in demos[0].keys():
            return [
                f"demos.sac_share: {cfg.demos.path} holds states only; SAC needs the agent's actions and "
                "the states they were taken in (drs-demos records them in the agent's controller, as does --from-policy)"
            ]
        have, want = int(demos[0]["action"].shape[-1]), int(self.env.action_spec.shape[-1])
        if have != want:
            mode = self._control_mode(cfg)
            return [
                f"demos.sac_share: the actions in {cfg.demos.path} are {have}-dimensional; this run acts with "
                f"{want}-dimensional {mode} commands. Record the demonstrations in the agent's controller "
                f"(drs-demos --control-mode {mode}, the default, or drs-demos --from-policy), or set demos.sac_share=0"
            ]
        root_keys = [k for k in self.loss.in_keys if isinstance(k, str) and k != "action"]
        missing = [k for k in root_keys if k not in demos[0].get("state").keys()]
        if missing:
            return [f"demos.sac_share: the demonstrations' states lack {missing}, which SAC reads"]
        return []

    def _demo_transitions(self, cfg, demos):
        """RLPD-style share of demonstrations in every SAC batch (``demos.sac_share``): a replay buffer of
        the demonstrations' transitions, whose rewards the learned reward recomputes at sampling like
        every other sample's. ``auto`` (the default) takes :data:`AUTO_SAC_SHARE` where the demonstrations
        allow it and says so, 0 where they do not and says why. Returns ``(buffer, transitions per SAC batch)``
        or ``(None, 0)``."""
        asked = requested_sac_share(cfg)
        if asked == 0:
            return None, 0
        if asked is None and not demos:  # auto, and no demonstrations (or no reward learned here): nothing to share
            cfg.demos.sac_share = 0.0
            return None, 0
        problems = self._sac_share_problems(cfg, demos)
        if asked is None:
            share = 0.0 if problems else AUTO_SAC_SHARE
            tqdm.write(
                f"drs-{self.phase}: demos.sac_share=auto -> {share:g}: "
                + (
                    problems[0]
                    if problems
                    else f"a share of every SAC batch from the {len(demos)} demonstrations' transitions "
                    "(beyond the paper: demos.sac_share=0 is its phase 1; results/demos_compare/pick_cube/)"
                )
            )
            cfg.demos.sac_share = share  # saved resolved: a resume keeps this run's choice
            if share == 0:
                return None, 0
        elif problems:
            raise ConfigError(problems[0])
        else:
            share = asked
        root_keys = [k for k in self.loss.in_keys if isinstance(k, str) and k != "action"]
        next_keys = list(dict.fromkeys([*root_keys, *self.learned.reward_in_keys, "stage"]))
        rows = []
        for ep in demos:
            T = ep.shape[0]
            ends = torch.zeros(T, 1, dtype=torch.bool)
            ends[-1] = bool(ep["success"][-1])  # demonstrations end on success
            nxt = TensorDict({k: ep.get(k) for k in next_keys}, batch_size=[T])
            nxt.update(
                {
                    "reward": torch.zeros(T, 1),
                    "done": ends.clone(),
                    "terminated": ends.clone(),
                    "truncated": torch.zeros(T, 1, dtype=torch.bool),
                }
            )
            rows.append(
                TensorDict(
                    {**{k: ep.get("state").get(k) for k in root_keys}, "action": ep.get("action"), "next": nxt},
                    batch_size=[T],
                )
            )
        buffer = ReplayBuffer(
            storage=LazyTensorStorage(sum(r.shape[0] for r in rows), device=self.device), transform=self.learned
        )
        buffer.extend(torch.cat(rows, 0).to(self.device))
        n = max(1, round(share * int(cfg.algo.batch_size)))
        return buffer, n

    def sac_batch(self) -> TensorDict:
        """One SAC batch from the replay buffer (and the demonstrations' share), rewards recomputed."""
        if self.demo_replay is None:
            return self.replay.sample().to(self.device)
        demo = self.demo_replay.sample(self._demo_batch)
        agent = self.replay.sample().to(self.device).select(*demo.keys(True, True))
        return torch.cat([agent, demo.to(self.device)], 0)

    # --------------------------------------------------------------- evaluation
    def evaluate(self) -> dict[str, float]:
        n = int(self.cfg.eval.episodes)
        if n == 0:
            return {}
        episodes, first_seed = [], self.cfg.eval.get("episode_seed")
        with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
            for j in range(n):
                if first_seed is not None:  # a seeded reset: the same n episodes at every evaluation, in every run
                    self.eval_env.set_seed(int(first_seed) + j, static_seed=True)
                ep = self.eval_env.rollout(10_000, self.actor, break_when_any_done=True)
                while ep.batch_dims > 1:  # a GPU env with num_envs=1 has batch (1, T)
                    ep = ep[0]
                episodes.append(episode_summary(ep, self.episode_reward))
        return aggregate_episodes(episodes, self.num_stages)

    # -------------------------------------------------------------- checkpoints
    def save_checkpoints(self) -> dict[str, str]:
        """The user-facing checkpoints: the learned reward (phase 1) and the policy."""
        ck = self.run_dir / "checkpoints"
        paths = {}
        if self.learner is not None:
            paths["reward"] = str(self.learner.save_reward(ck / "reward.pt", frames=self.frames, phase=self.phase))
        policy = {
            "format": POLICY_FORMAT,
            "version": 1,
            "frames": self.frames,
            "family": self.family.name,
            "policy_in_keys": list(self.cfg.algo.policy_in_keys),
            "hidden": list(self.cfg.algo.hidden),
            "actor": self.actor.state_dict(),
            # SACLoss trains its own stacked copies of the critics (one per Q-net), not self.qvalue
            "qvalue_params": self.loss.qvalue_network_params.data.cpu().to_dict(),
            "num_qvalue_nets": int(self.loss.num_qvalue_nets),
            "log_alpha": self.loss.log_alpha.detach().cpu(),
        }
        # the training state written next must fit too: a run never holds checkpoints newer than its state
        reward = nbytes(self.learner.reward.state_dict()) if self.learner is not None else 0
        ensure_free(
            ck,
            nbytes(policy) + reward + self._state_bytes(self._state_payload()),
            "the checkpoints and training state in",
        )
        atomic_torch_save(policy, ck / "policy.pt")
        paths["policy"] = str(ck / "policy.pt")
        return paths

    def _optimizers(self) -> dict[str, torch.optim.Optimizer]:
        return self.optimizers

    def save_training_state(self) -> Path:
        """Everything needed to continue the run, written atomically to ``checkpoints/state``.

        Networks, target networks and entropy coefficient (the SAC loss module's state), optimisers,
        discriminators and their early-stop window, replay buffer and stage buffers (memory-mapped
        TensorDicts of the filled slots only), step counters, RNG states and recent-episode statistics.
        A new state is written beside the old one and swapped in by renames, so a crash while
        writing leaves the previous state usable; SIGINT/SIGTERM arriving meanwhile are delivered after.
        """
        with _signals_deferred():
            return self._write_training_state()

    def _write_training_state(self) -> Path:
        ck = self.run_dir / "checkpoints"
        final, tmp, old = ck / "state", ck / f"state.tmp-{os.getpid()}", ck / "state.old"
        for stale in ck.glob("state.tmp-*"):  # left by a process killed while saving
            shutil.rmtree(stale, ignore_errors=True)
        if (final / "COMPLETE").is_file():
            shutil.rmtree(old, ignore_errors=True)  # a fallback left by a crash while swapping: state is newer
        payload = self._state_payload()
        # checked before writing: memory-mapped buffers on a full disk fault (SIGBUS) instead of raising
        ensure_free(ck, self._state_bytes(payload), "the training state in")
        try:
            with space_errors(tmp, "the training state"):
                tmp.mkdir(parents=True)
                dump_buffer(self.replay, tmp / "replay")
                if self.learner is not None:
                    self.learner.dump_buffers(tmp)
                with open(tmp / "trainer.pt", "wb") as f:  # an open file: a full disk raises ENOSPC, not a RuntimeError
                    torch.save(payload, f)
                (tmp / "COMPLETE").write_text(str(self.frames))
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)  # the last complete state stays as it was
            raise
        # swap in: at every instant one complete state exists (final, else old)
        if (final / "COMPLETE").is_file():
            shutil.rmtree(old, ignore_errors=True)
            final.rename(old)
        elif final.exists():
            shutil.rmtree(final)  # a partial state left by a crash; old (if any) stays the fallback
        tmp.rename(final)
        shutil.rmtree(old, ignore_errors=True)
        return final

    def _state_payload(self) -> dict:
        """The training state apart from the buffers (``trainer.pt``)."""
        return {
            "format": STATE_FORMAT,
            "version": STATE_VERSION,
            "phase": self.phase,
            "counters": {
                "frames": self.frames,
                "updates": self.updates,
                "disc_updates": self.disc_updates,
                "owed_updates": self._owed_updates,
                "last_eval_frames": self._last_eval_frames,
            },
            "loss": self.loss.state_dict(),
            "optimizers": {k: o.state_dict() for k, o in self._optimizers().items()},
            "learner": self.learner.state_dict() if self.learner is not None else None,
            "recent_episodes": list(self.recent),
            "rng": {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()},
        }

    def _state_bytes(self, payload: dict) -> int:
        """About the bytes the training state takes on disk: ``payload``'s tensors and the buffers' filled slots."""
        learner_buffers = (
            [b for b in vars(self.learner).values() if isinstance(b, ReplayBuffer)] if self.learner else []
        )
        return nbytes(payload) + sum(
            buffer_bytes(b) for b in {id(b): b for b in [self.replay, *learner_buffers]}.values()
        )

    def load_training_state(self) -> None:
        state_dir = find_training_state(self.run_dir)
        try:
            payload = torch.load(state_dir / "trainer.pt", map_location="cpu", weights_only=False)
        except Exception as exc:
            why = str(exc).split(". ")[0].split("\n")[0]
            raise TrainingStateError(
                f"{state_dir / 'trainer.pt'} cannot be read (corrupt or truncated: {why}); the run cannot "
                "continue from it: start it afresh with overwrite=true (its checkpoints/reward.pt and "
                "policy.pt are separate files: copy them first to keep them)"
            ) from exc
        if payload.get("format") != STATE_FORMAT or int(payload.get("version", 99)) > STATE_VERSION:
            raise TrainingStateError(f"{state_dir} was not written by this version of drs-torchrl")
        if payload["phase"] != self.phase:
            raise TrainingStateError(
                f"{self.run_dir} is a drs-{payload['phase']} run; resume it with drs-{payload['phase']}"
            )
        c = payload["counters"]
        self.frames, self.updates = int(c["frames"]), int(c["updates"])
        self._owed_updates, self._last_eval_frames = float(c["owed_updates"]), int(c["last_eval_frames"])
        self.loss.load_state_dict(payload["loss"])
        opts = self._optimizers()
        for k, sd in payload["optimizers"].items():
            if k in opts:
                opts[k].load_state_dict(sd)
        try:
            if self.learner is not None:
                state = payload.get("learner")
                if state is None:  # written before the reward learners existed: a DrS run's parts at the top level
                    state = {
                        "reward": payload["reward"],
                        "disc_loss": payload["disc_loss"],
                        "updates": int(c["disc_updates"]),
                        "optimizers": {"discriminator": payload["optimizers"]["discriminator"]},
                        "stage_buffer_episodes": payload["stage_buffer_episodes"],
                    }
                self.learner.load_state_dict(state)
                self.learner.load_buffers(state_dir)
            load_buffer(self.replay, state_dir / "replay")
        except (SnapshotError, OSError, KeyError, RuntimeError) as exc:
            raise TrainingStateError(f"the training state in {state_dir} is damaged: {exc}") from exc
        self.recent.extend(tuple(e) for e in payload["recent_episodes"])
        stored = self.replay.storage._storage if len(self.replay) else None
        if stored is not None and any(k in stored.keys() for k in self._replay_exclude):
            self._replay_exclude = ()  # a run whose replay buffer was started with every key keeps them
        torch.set_rng_state(payload["rng"]["torch"])
        np.random.set_state(payload["rng"]["numpy"])
        random.setstate(payload["rng"]["python"])

    # --------------------------------------------------------------------- run
    def _check_finite(self, what: str, value: torch.Tensor) -> None:
        if not bool(torch.isfinite(value).all()):
            raise NonFiniteError(
                f"non-finite {what} at env step {self.frames} (SAC update {self.updates}); the run stopped "
                f"without saving, so the last good checkpoint in {self.run_dir / 'checkpoints'} is intact"
            )

    @property
    def collects_in_background(self) -> bool:
        """True when the configured collector steps the env in its own process (``collects_in_background``)."""
        return collects_in_background(self.cfg)

    def _collector_env(self):
        """The env for the collector: the trainer's own env for an in-process collector, else a
        picklable constructor of the same env, which the collector's worker process calls.

        The worker env is seeded like the trainer's (``seed``; ``seed + 1 + frames`` on resume) and
        carries the same transforms (stage labelling, and a frozen reward in phase 2). The worker
        ignores SIGINT: Ctrl-C reaches the whole process group, and the trainer decides how to stop.
        """
        if not self.collects_in_background:
            return self.env
        seed = int(self.cfg.seed) + (1 + self.frames if self.resumed_from is not None else 0)
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
            return functools.partial(_background_worker_env, make)

        if issubclass(get_class(self.cfg.algo.collector._target_), AsyncCollector):
            return factory(0)
        # MultiAsyncCollector / MultiSyncCollector: one differently seeded env per worker process
        return [factory(w) for w in range(int(self.cfg.algo.collector.get("num_workers") or 1))]

    def make_collector(self, frames: int):
        """The configured TorchRL collector for the next ``frames`` env steps, acting with
        ``self.actor`` (random actions until ``algo.learning_starts``)."""
        return make_collector(self.cfg, self._collector_env(), self.actor, frames, self.frames, self.device)

    def run(self) -> dict[str, Any]:
        """Algorithm 1 from where the run stands to ``total_frames`` env steps; returns the summary."""
        cfg = self.cfg
        total = int(cfg.total_frames)
        summary: dict[str, Any] = {
            "phase": self.phase,
            "run_dir": str(self.run_dir),
            "resumed_from": self.resumed_from,
            "precision": self.precision,
            "init_from": cfg.get("init_from"),
            "code": code_version(),
        }
        tqdm.write(f"drs-{self.phase}: {describe_precision(self.precision, self.device)}")
        for note in self.notes:
            tqdm.write(f"drs-{self.phase}: {note}")
        if self.learner is not None and self.frames == 0 and self.resumed_from is None:
            self.learner.prepare(self.env)  # e.g. ORIL's offline classifier, before the first env step
        if total - self.frames > 0:
            self.collector = self.make_collector(total - self.frames)
            if self.collects_in_background and not self.env.is_closed:
                self.env.close()  # its specs were all the trainer needed; the worker has its own simulator
        bar = tqdm(
            total=total,
            initial=self.frames,
            desc=f"drs-{self.phase}",
            unit="step",
            disable=not cfg.logger.progress_bar,
            dynamic_ncols=True,
        )
        stop = _StopRequest()
        previous = stop.install()  # stays until run() returns: the final eval and saves stop cleanly too
        try:
            return self._run_loop(stop, summary, bar)
        finally:
            stop.uninstall(previous)

    def _run_loop(self, stop, summary, bar) -> dict[str, Any]:
        """The loop of Algorithm 1: collect, file episodes, update the reward learner and SAC at the
        configured UTD, and log / evaluate / checkpoint on schedule, until the budget or a signal."""
        cfg, win = self.cfg, _Window()
        log_at, eval_at, ckpt_at = (
            _Every(int(i), self.frames) for i in (cfg.logger.interval, cfg.eval.interval, cfg.checkpoint_interval)
        )
        it = iter(self.collector) if self.collector is not None else iter(())
        t0, frames0, interrupted, forced = time.perf_counter(), self.frames, False, False
        try:
            while (batch := win.timed("collect", next, it, None)) is not None:
                n = self._store(batch)  # replay buffer, finished episodes, the reward learner's observe()
                win.timed("update", self._update, n, win)
                win.frames += n
                bar.update(n)
                if log_at.due(self.frames):
                    row = self._train_row(win)
                    self.logger.log("train", self.frames, row)
                    bar.set_postfix(success=f"{row.get('success_rate', 0):.2f}", sps=f"{row['env_steps_per_s']:.0f}")
                    win = _Window()
                    if self._reached_stop_success(row, summary):
                        break
                if eval_at.due(self.frames):
                    self._evaluate_and_log(summary)
                if ckpt_at.due(self.frames):
                    self.save_checkpoints()
                    self.save_training_state()
                    self.logger.flush()
                if stop.signum is not None:  # SIGINT/SIGTERM: stop here, between two rounds
                    interrupted, summary["signal"] = True, int(stop.signum)
                    tqdm.write(
                        f"signal {stop.signum} at {self.frames} env steps: saving the training state in "
                        f"{self.run_dir / 'checkpoints'}"
                    )
                    break
        except KeyboardInterrupt:  # a second Ctrl-C forces the stop wherever the loop was
            interrupted = forced = True
            summary["signal"] = int(signal.SIGINT)
            tqdm.write(
                f"forced stop at {self.frames} env steps: the last periodic training state is kept "
                "(the buffers may be mid-write, so nothing is saved now)"
            )
        except Exception:  # NaN, a full disk, ...: the collector's worker must not outlive the run
            bar.close()
            self.close()
            raise
        finally:
            bar.close()
        try:
            return self._finish(summary, win, t0, frames0, interrupted, forced)
        except Exception:
            self.close()
            raise

    def _reached_stop_success(self, row: dict, summary: dict) -> bool:
        """``stop_at_success``: the training success rate over a full episode window reached it (phase 1
        "until the agent succeeds"); the run then ends as finished, with its final evaluation and saves."""
        target = self.cfg.get("stop_at_success")
        if target is None or len(self.recent) < self.recent.maxlen or row.get("success_rate", 0.0) < float(target):
            return False
        summary["stopped_at_success"] = {
            "success_rate": float(row["success_rate"]),
            "threshold": float(target),
            "frames": int(self.frames),
            "episodes": len(self.recent),
        }
        tqdm.write(
            f"drs-{self.phase}: training success {row['success_rate']:.2f} over the last {len(self.recent)} episodes "
            f">= stop_at_success={float(target):g} at {self.frames} env steps: stopping"
        )
        return True

    def _store(self, batch) -> int:
        """A collected batch into the replay buffer; its finished episodes to the statistics and to
        the reward learner (DrS files them by stage; VICE-RAQ labels every state)."""
        self._check_finite("observations", batch.get(("next", "observation")))
        n = batch.numel()
        self.frames += n
        self.replay.extend(batch.exclude(*self._replay_exclude).reshape(-1))
        episodes = self.assembler.add(batch)
        if episodes:
            self.recent.extend(episode_summary(ep, self.episode_reward) for ep in episodes)
        if self.learner is not None:
            self.learner.observe(batch, episodes)
        return n

    def _update(self, n: int, win: "_Window") -> None:
        """``algo.utd`` updates per collected env step, once learning has started: the reward
        learner's step, then SAC's (the learned reward recomputed on its batch)."""
        a = self.cfg.algo
        if self.frames < int(a.learning_starts) or len(self.replay) < int(a.batch_size):
            return
        self._owed_updates += n * float(a.utd)
        k = int(self._owed_updates)
        self._owed_updates -= k
        for _ in range(k):
            if self.learner is not None and (d := self.learner.update()) is not None:
                win.disc.append(d)
            out, r = self._sac_step()
            win.sac.append(out)
            win.rewards.append(r)
        win.updates += k
        if k and self.collector is not None and self.collects_in_background:
            self.collector.update_policy_weights_()  # the worker collects the next batch with the updated actor

    def _evaluate_and_log(self, summary: dict) -> None:
        ev = self.evaluate()
        self._last_eval_frames = self.frames
        if ev:
            self.logger.log("eval", self.frames, ev)
            summary["last_eval"] = ev

    def _finish(
        self, summary: dict, win: "_Window", t0: float, frames0: int, interrupted: bool, forced: bool
    ) -> dict[str, Any]:
        """The last rows, a final evaluation (unless interrupted), the saves (unless forced) and ``summary.json``."""
        elapsed = time.perf_counter() - t0
        if win.frames:
            self.logger.log("train", self.frames, self._train_row(win))
        if not interrupted and self._last_eval_frames != self.frames:
            self._evaluate_and_log(summary)
        if not forced:
            summary["checkpoints"] = self.save_checkpoints()
            self.save_training_state()
        else:
            summary["frames_at_last_state"] = int(self.frames)  # informational; resume uses the saved state
        summary.update(
            frames=self.frames,
            updates=self.updates,
            disc_updates=self.disc_updates,
            wall_time_s=elapsed,
            env_steps_per_s=(self.frames - frames0) / max(elapsed, 1e-9),
            interrupted=interrupted,
        )
        if self.learner is not None:
            summary.update(self.learner.summary())
        atomic_write_text(self.run_dir / "summary.json", json.dumps(summary, indent=2))
        self.close()
        return summary

    def _sac_step(self) -> tuple[TensorDict, torch.Tensor]:
        sample = self.sac_batch()  # the learned reward is recomputed here, in fp32
        with autocast(self.precision, self.device):
            out = self._loss_fn(sample)
        total = out["loss_actor"] + out["loss_qvalue"] + out["loss_alpha"]
        self._check_finite("SAC loss", total.detach())
        opts = (self.optim_actor, self.optim_critic, self.optim_alpha)
        for opt in opts:
            opt.zero_grad(set_to_none=True)
        self._backward_and_step(total, opts)
        self.target_updater.step()
        self.updates += 1
        return out.detach(), sample.get(("next", "reward")).detach()

    def _backward_and_step(self, loss: torch.Tensor, optimizers) -> None:
        """Backward pass and optimiser steps, through the fp16 gradient scaler when there is one."""
        backward_and_step(self._grad_scaler, loss, optimizers)

    def _train_row(self, win: "_Window") -> dict[str, float]:
        dt, frames, updates = time.perf_counter() - win.t0, win.frames, win.updates
        t_collect, t_update = win.seconds["collect"], win.seconds["update"]
        row: dict[str, float] = {
            "frames": self.frames,
            "updates": self.updates,
            "env_steps_per_s": frames / max(dt, 1e-9),
            "updates_per_s": updates / max(t_update, 1e-9) if updates else 0.0,
            "collect_steps_per_s": frames / max(t_collect, 1e-9),
            # where the trainer's wall time went: waiting for the collector (all of the simulation, for
            # an in-process collector; only the part not overlapped, for a background one) vs updating
            "frac_time_waiting_for_data": t_collect / max(dt, 1e-9),
            "frac_time_updating": t_update / max(dt, 1e-9),
        }
        if self.recent:
            row.update(aggregate_episodes(list(self.recent), self.num_stages))
        if win.sac:
            st = torch.stack([s.select("loss_actor", "loss_qvalue", "loss_alpha", "alpha", "entropy") for s in win.sac])
            for k in st.keys():
                row[k] = float(st[k].float().mean())
        if win.rewards:
            r = torch.cat(win.rewards)
            self._check_finite("rewards", r)
            row.update(
                reward_mean=float(r.mean()),
                reward_std=float(r.std()),
                reward_min=float(r.min()),
                reward_max=float(r.max()),
            )
        if win.disc:
            st = torch.stack(win.disc)
            for k in st.keys():
                row[f"disc_{k}"] = float(st[k].float().mean())
        if self.learner is not None:
            row.update(self.learner.log_row())
        return row

    def close(self) -> None:
        if self.logger is not None:
            self.logger.close()
        if self.collector is not None:
            try:
                self.collector.shutdown()
            except Exception:
                pass
            self.collector = None  # freed now, not at interpreter exit (see step_fn above)
        for env in (self.env, self.eval_env):
            if env is not None and not env.is_closed:
                env.close()


class _Window:
    """What happened since the last train-log row: SAC and reward-learner statistics, sampled
    rewards, env steps, updates, and the seconds spent waiting for data and updating (TorchRL's
    ``timeit`` timers ``drs/collect`` and ``drs/update``, read as differences so that other
    ``timeit`` users in the process are left alone)."""

    TIMERS = ("collect", "update")

    def __init__(self):
        self.sac: list[TensorDict] = []
        self.disc: list[TensorDict] = []
        self.rewards: list[torch.Tensor] = []
        self.frames = self.updates = 0
        self._start = self._totals()
        self.t0 = time.perf_counter()

    @classmethod
    def _totals(cls) -> dict[str, float]:
        totals = timeit.todict(percall=False)
        return {w: totals.get(f"drs/{w}", 0.0) for w in cls.TIMERS}

    @property
    def seconds(self) -> dict[str, float]:
        now = self._totals()
        return {w: now[w] - self._start[w] for w in self.TIMERS}

    def timed(self, what: str, fn, *args):
        with timeit(f"drs/{what}"):
            return fn(*args)


class _Every:
    """Due every ``interval`` env steps, counted from 0 (a resumed run keeps the same schedule)."""

    def __init__(self, interval: int, frames: int):
        self.interval = interval
        self.next = (frames // interval + 1) * interval

    def due(self, frames: int) -> bool:
        if frames < self.next:
            return False
        self.next = (frames // self.interval + 1) * self.interval
        return True


def backward_and_step(grad_scaler, loss: torch.Tensor, optimizers) -> None:
    """Backward pass and optimiser steps, through an fp16 gradient scaler when there is one."""
    if grad_scaler is None:
        loss.backward()
        for opt in optimizers:
            opt.step()
        return
    grad_scaler.scale(loss).backward()
    for opt in optimizers:
        grad_scaler.step(opt)
    grad_scaler.update()


class TrainingStateError(UserError, RuntimeError):
    """A run directory whose training state cannot be resumed."""


class NonFiniteError(RuntimeError):
    """NaN or inf in observations, rewards or losses."""


STATE_FORMAT = "drs-torchrl/training-state"
STATE_VERSION = 1


def find_training_state(run_dir: Path) -> Path:
    """The newest complete training state of ``run_dir`` (``state``, else ``state.old``)."""
    ck = Path(run_dir) / "checkpoints"
    for name in ("state", "state.old"):
        if (ck / name / "COMPLETE").is_file():
            return ck / name
    if not Path(run_dir).is_dir():
        raise TrainingStateError(f"cannot resume: {run_dir} does not exist")
    raise TrainingStateError(
        f"cannot resume: {run_dir} has no complete training state in checkpoints/ (a run saves one every "
        "checkpoint_interval env steps and when it is interrupted)"
    )


def atomic_torch_save(obj, path: Path) -> None:
    """``torch.save`` into a temporary file renamed over ``path``: ``path`` is the old file or the new one,
    never a part (a full disk raises :class:`~drs_torchrl.rundir.DiskFullError` and leaves the old one)."""
    _atomic_write(path, lambda f: torch.save(obj, f), "wb")


def atomic_write_text(path: Path, text: str) -> None:
    _atomic_write(path, lambda f: f.write(text), "w")


def _atomic_write(path: Path, write, mode: str) -> None:
    tmp = path.with_name(path.name + f".tmp-{os.getpid()}")
    try:
        with space_errors(path, "the file"), open(tmp, mode) as f:
            write(f)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


class _StopRequest:
    """SIGINT/SIGTERM handler of the training loop: it records the request and the loop stops at the
    next batch boundary. Raising inside TorchRL/tensordict code (what Python's default SIGINT does) can
    leave library context managers in a broken state; a second SIGINT still forces KeyboardInterrupt."""

    def __init__(self):
        self.signum: int | None = None

    def __call__(self, signum, frame):
        if self.signum is not None and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.signum = signum

    def install(self) -> dict:
        if not _in_main_thread():
            return {}
        return {sig: signal.signal(sig, self) for sig in (signal.SIGINT, signal.SIGTERM)}

    @staticmethod
    def uninstall(previous: dict) -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


class _signals_deferred:
    """Hold SIGINT/SIGTERM while a checkpoint is written; re-deliver them once it is complete."""

    def __enter__(self):
        self.pending = []
        self.previous = {}
        if not _in_main_thread():
            return self
        for sig in (signal.SIGINT, signal.SIGTERM):
            self.previous[sig] = signal.signal(sig, lambda signum, frame: self.pending.append(signum))
        return self

    def __exit__(self, *exc):
        for sig, handler in self.previous.items():
            signal.signal(sig, handler)
        for sig in dict.fromkeys(self.pending):
            signal.raise_signal(sig)  # to the handler in place again (the loop's stop request)
        return False


def _in_main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


def _background_worker_env(make_env):
    """Build the env in a background collector's worker process, which ignores SIGINT (see
    :meth:`Trainer._collector_env`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if os.environ.get("DRS_QUIET_LIBRARIES") == "1":
        from drs_torchrl.console import quiet_libraries

        quiet_libraries()
    return make_env()


def train(cfg: DictConfig, phase: str, run_dir: str | Path, *, resume: bool = False) -> dict[str, Any]:
    """Run (or, with ``resume=True``, continue) one phase with the Hydra config ``cfg``."""
    trainer = Trainer(cfg, phase, run_dir, resume=resume)
    return trainer.run()
