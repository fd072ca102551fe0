"""``drs-maze``: the paper's navigation experiment (Appendix, "Navigation"), one-stage DrS with DQN.

Phase 1 (``phase=learn``, train map) runs Algorithm 1 with one stage (success). A DQN agent trains
on the learned reward. Every finished episode goes into the stage buffers, and the discriminator
learns "comes from a successful episode" vs "from a failed one". As in the appendix, the reward is
a function of the state-action pair (the paper's tabular analysis writes
``R(s, a) = tanh(D(s, a))``). The discriminator reads the observation concatenated with the one-hot
action, and the reward of a transition is the rescaled Eq. 4 with the stage of its next state:
``k + alpha * tanh(D(s, a)) - 2``. A failed step then earns about -2 and the success step -1.
Phase 2 (``phase=reuse``, test map, moved gates) trains a fresh DQN agent with the frozen reward
(``reward.name=drs reward.checkpoint=.../reward.pt``). The baselines in the same slot are
``sparse`` (1 on success, the paper's baseline) and ``semi_sparse`` (``k - 1``: -1 a step, 0 on
success, which is the constant part of the DrS reward without the learned term) and ``dense``
(human-engineered: ``success - d(s') / d_max`` with ``d`` the map's shortest-path distance to the goal).
``phase=report`` gathers the runs under ``report.root`` into a curve PNG, a CSV and a Markdown table.

Choices the paper leaves open, or where this script departs from it (all in ``conf/maze.yaml``):

* Demonstrations (Algorithm 1, line 3, optional in the paper): ``demos=100`` shortest-path
  episodes of the train map go into the success buffer. Without them, epsilon-greedy DQN on this
  map met no success in 300k steps of phase 1 (a uniform random walk succeeds in about 0.15% of
  200-step episodes), so the discriminator never trained.
* n-step TD targets (``dqn.n_steps``, TorchRL's ``MultiStepTransform``) for every reward, so that
  the goal's value travels back along 30-50-step routes within a CPU budget. The n-step sums are
  made when transitions are stored, so in phase 1 the env writes ``R(s, a)`` with the discriminator
  of that moment. With ``dqn.n_steps=1`` the reward is instead recomputed from the current
  discriminator whenever the agent samples, as in Algorithm 1.
* ``train_success`` (in ``train.csv``) is the success rate of the last 100 *finished* training
  episodes. Successful episodes end early and so finish more often, which biases this rate upward.
  ``eval_success`` (one greedy episode in each of ``eval.episodes`` grids) is the unbiased figure.

It is a DQN script in the shape of TorchRL's ``sota-implementations``: the maze's pieces come from
:mod:`drs_torchrl.tasks.maze` (the env with its stage label and reward slot, the shortest-path demonstrations, the
(s, a) episodes for the stage buffers, greedy evaluation), the agent from ``conf/algo/dqn.yaml`` (placed at ``dqn``;
:func:`~drs_torchrl.updaters.dqn.make_dqn_updater`) or ``conf/algo/ppo.yaml`` (placed at ``ppo`` with the maze's
values; :func:`~drs_torchrl.updaters.ppo.make_ppo_updater`), the reward from :func:`make_reward`, and one loop in
:func:`train` (:func:`~drs_torchrl.loop.run_algorithm1`). DrS itself is the same reward-learning core as the
SAC families' (:class:`~drs_torchrl.learners.DrSLearner`: stage buffers, ``DiscriminatorLoss``,
demonstrations), and the run is logged through the same TorchRL loggers. The reward figure,
diagnostics and report live in :mod:`drs_torchrl.tools.maze_analysis`.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import sys
import time
from pathlib import Path

import hydra
import numpy as np
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDict
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.envs.transforms import MultiStepTransform

from drs_torchrl.runtime.checkpoint import (
    Checkpointer,
    TrainingStateError,
    find_training_state,
)
from drs_torchrl.runtime.provenance import code_version
from drs_torchrl.envs.maze import ACTIONS, GATES, OBS_DIMS
from drs_torchrl.learners import (
    DemoDiscriminatorLearner,
    DrSLearner,
    OfflineClassifierLearner,
    SuccessClassifierLearner,
)
from drs_torchrl.tasks.maze import (
    FAMILY,
    REWARD_INPUTS,
    MazeConfigError,
    convertible,
    demo_episodes,
    evaluate_greedy,
    make_env,
    reads_next_state,
    reward_coords,
    reward_transform,
    sa_trajectory,
)
from drs_torchrl.tools.maze_analysis import (
    plot_reward_map,
    report,
    reward_diagnostics,
)
from drs_torchrl.apps.hydra_record import (  # (registers the resolver)
    EMPTY_RUN_DIR,
    current_record,
    discard_refused_record,
    empty_run_dir,
    replaced,
)
from drs_torchrl.apps.overrides import check_added_settings, check_constructor_arguments
from drs_torchrl.apps.schema import MazeSchema, check
from drs_torchrl.config_dir import conf_dir
from drs_torchrl.runtime.console import console_script
from drs_torchrl.runtime.run_logger import RunLogger
from drs_torchrl.loop import EpisodeWindow, Progress, Schedule, run_algorithm1
from drs_torchrl.apps.reward_registry import available_rewards, registry_entry
from drs_torchrl.rewards import static_checkpoint_error
from drs_torchrl.runtime.rundir import (
    RunFileError,
    load_run_config,
    maze_run_message,
    OldRun,
    RunDirBusyError,
    clear_for_new_run,
    lock_run_dir,
    unlock_run_dir,
)
from drs_torchrl.transforms import (
    ClassifierReward,
    DrSReward,
    load_reward,
)


def _entry(cfg: DictConfig):
    """The reward's registry entry (``conf/reward/<name>.yaml``), or None for a name it does not hold."""
    return registry_entry(cfg.reward.name) if cfg.reward.name in available_rewards() else None


def _is_classifier(entry) -> bool:
    """A learned baseline whose reward is one classifier (its entry says what it separates, or reuses one)."""
    return entry is not None and entry.get("learner") is not None and (entry.get("trains_on") or entry.get("reuses"))


def validate(cfg: DictConfig) -> None:
    """The schema's types and ranges (``apps/schema.py``), then the rules between fields and the registry's names."""
    check(cfg, MazeSchema, MazeConfigError)
    check_constructor_arguments(cfg, MazeConfigError)
    entry, name = _entry(cfg), cfg.reward.name
    learned = entry is not None and entry.get("learner") is not None
    learnable = [n for n in available_rewards() if (e := registry_entry(n)).get("learner")
                 and not e.get("reuses")]  # fmt: skip
    checks = [
        (cfg.phase in ("learn", "reuse", "report"), f"phase must be learn, reuse or report, got {cfg.phase!r}"),
        (entry is not None, f"reward.name must be one of {available_rewards()} (conf/reward/), got {name!r}"),
        (
            cfg.phase != "learn" or entry is None or name in learnable,
            f"phase=learn learns one of {learnable} (static baselines, and rewards that reuse another's checkpoint, "
            "run with phase=reuse)",
        ),
        (cfg.phase != "learn" or not cfg.reward.checkpoint, "reward.checkpoint is for phase=reuse"),
        (
            entry is None or learned or not cfg.reward.checkpoint,
            static_checkpoint_error(name, cfg.reward.checkpoint, key="reward.name"),
        ),
        (
            cfg.phase != "reuse" or not learned or bool(cfg.reward.checkpoint),
            f"phase=reuse with reward.name={name} needs reward.checkpoint=PATH (a reward.pt written by phase=learn"
            f" reward.name={entry.get('reuses') or name if entry is not None else name})",
        ),
        (
            not _is_classifier(entry) or cfg.reward.get("coords") in (None, cfg.coords),
            "the classifier baselines read the agent's own observation: leave reward.coords=null",
        ),
        (
            cfg.phase != "learn"
            or entry is None
            or entry.get("trains_on") not in ("demos_vs_random", "demos_vs_agent")
            or cfg.demos > 0,
            f"reward.name={name} learns from demonstrations: set demos > 0",
        ),
        (cfg.map is None or cfg.map in GATES, f"map must be null or one of {sorted(GATES)}, got {cfg.map!r}"),
        (cfg.get("agent", "dqn") in ("dqn", "ppo"), f"agent must be dqn or ppo, got {cfg.get('agent')!r}"),
        (
            cfg.ppo.get("precision", "fp32") == "fp32",  # conf/algo/ppo.yaml's setting; the maze's agents run fp32
            f"the maze's PPO runs in fp32 (its networks are 64 wide): leave ppo.precision=fp32, got {cfg.ppo.precision}",
        ),
        (
            algo_config(cfg).frames_per_batch % cfg.num_envs == 0,
            f"{cfg.get('agent', 'dqn')}.frames_per_batch ({algo_config(cfg).frames_per_batch}) must be a multiple of "
            f"num_envs ({cfg.num_envs})",
        ),
        (
            cfg.reward.get("input", "state_action") in REWARD_INPUTS,
            f"reward.input must be one of {REWARD_INPUTS}, got {cfg.reward.get('input')!r}",
        ),
        (
            cfg.reward.get("positives", "all") in ("all", "demos"),
            f"reward.positives must be all or demos, got {cfg.reward.get('positives')!r}",
        ),
        (
            cfg.reward.get("positives", "all") != "demos" or cfg.demos > 0,
            "reward.positives=demos makes the demonstrations the only positives: set demos > 0",
        ),
        (cfg.coords in OBS_DIMS, f"coords must be one of {sorted(OBS_DIMS)}, got {cfg.coords!r}"),
        (
            cfg.reward.get("coords") in (None, *OBS_DIMS),
            f"reward.coords must be null or one of {sorted(OBS_DIMS)}, got {cfg.reward.get('coords')!r}",
        ),
        (
            convertible(cfg.coords, cfg.reward.get("coords") or cfg.coords),
            f"a reward on coords={cfg.reward.get('coords')} cannot read the agent's coords={cfg.coords} observations "
            "(absolute positions cannot be recovered from relative ones): use reward.coords=relative, patch or null",
        ),
    ]
    bad = [msg for ok, msg in checks if not ok]
    if bad:
        raise MazeConfigError("; ".join(bad))


RUN_FILES = ("summary.json", "train.csv", "config.yaml", "reward.pt", "policy.pt", "checkpoints")


def check_run_dir(run_dir: Path, overwrite: bool) -> OldRun:
    """Refuse a directory that holds a maze run (its files would be mixed or overwritten), unless ``overwrite``: then
    that run's files are set aside (returned) for the caller to drop once the new run has started. A run a signal
    stopped holds its training state: the refusal says how to continue it."""
    stopped = (run_dir / "checkpoints" / "state" / "COMPLETE").is_file()
    return clear_for_new_run(
        run_dir,
        RUN_FILES,
        overwrite,
        error=MazeConfigError,
        options=(f"continue it with drs-maze resume={run_dir}, " if stopped else "") + "choose another hydra.run.dir",
        also=("reward_map.png",),
    )


# ----------------------------------------------------------------------------- factories
def make_reward(
    cfg: DictConfig, map_name: str, learn: bool, resume: bool = False
) -> tuple[DrSLearner | None, DrSReward | None]:
    """The DrS reward of the run: learned here by a :class:`~drs_torchrl.learners.DrSLearner` (phase 1,
    the same reward-learning core as the SAC families), frozen from a checkpoint (phase 2), or none
    (a baseline written by the env). ``resume``: the demonstrations are in the stage buffers' saved state."""
    r = cfg.reward
    if _is_classifier(_entry(cfg)):
        return make_classifier_reward(cfg, map_name, learn)
    if r.name != "drs":
        return None, None
    if not learn:
        drs = DrSReward.from_checkpoint(r.checkpoint)
        meta = drs.metadata
        if (
            meta.get("family") != FAMILY
            or drs.num_stages != 1
            or drs.reward_in_keys not in (["observation", "action"], ["observation"])
        ):
            raise MazeConfigError(
                f"{r.checkpoint} is not a maze reward (family {meta.get('family')!r}, inputs {drs.reward_in_keys})"
            )
        if not convertible(cfg.coords, reward_coords(drs)):
            raise MazeConfigError(
                f"{r.checkpoint} was learned with coords={reward_coords(drs)}, which this run's "
                f"coords={cfg.coords} observations cannot be re-encoded to; use coords={reward_coords(drs)}"
            )
        if r.get("reuse_offset") is not None:  # shift the frozen reward (the learned term is unchanged)
            drs.offset = float(r.reuse_offset)
        if r.get("reuse_alpha") is not None:  # reweight the learned term; 0 leaves DrS's constant part (the control)
            drs.alpha = float(r.reuse_alpha)
        return None, drs.requires_grad_(False)
    rc = r.get("coords") or cfg.coords
    on_next = r.get("input", "state_action") == "next_state"
    shapes = {"observation": OBS_DIMS[rc]} if on_next else {"observation": OBS_DIMS[rc], "action": len(ACTIONS)}
    drs = DrSReward(
        1,
        list(shapes),
        shapes,
        formula=r.formula,
        alpha=r.alpha,
        offset=r.offset,
        hidden=list(r.hidden),
        activation=r.activation,
        metadata={
            "family": FAMILY,
            "map": map_name,
            "reward_on": "next_state" if on_next else "state_action",
            "coords": rc,
            "seed": int(cfg.seed),
            "positives": r.get("positives", "all"),
        },
    )
    demos = (
        [ep.get("next") for ep in demo_episodes(map_name, int(cfg.demos), int(cfg.seed), rc, on_next)]
        if cfg.demos and not resume
        else []
    )
    learner = DrSLearner(
        drs,
        capacity=r.stage_buffer_size,
        batch_size=r.disc.batch_size,
        lr=r.disc.lr,
        reward_updates_per_update=cfg[cfg.agent].reward_updates_per_update,
        early_stop_threshold=r.disc.early_stop_threshold,
        window=r.disc.window,
        demos=demos,
        file_successes=r.get("positives", "all") == "all",
    )
    return learner, drs


def make_classifier_reward(cfg: DictConfig, map_name: str, learn: bool):
    """A baseline's :class:`~drs_torchrl.transforms.ClassifierReward` and its learner from
    :mod:`drs_torchrl.learners` (phase 1), or the frozen classifier (phase 2; ``gail_stages`` adds
    the stage term ``w_s * (k - 1)`` to a GAIL checkpoint, Appendix F.2)."""
    r, c = cfg.reward, cfg.reward.classifier
    entry = registry_entry(r.name)
    if not learn:
        rew = load_reward(r.checkpoint)
        want = str(entry.get("reuses") or r.name)
        if not isinstance(rew, ClassifierReward) or rew.metadata.get("family") != FAMILY or rew.method != want:
            raise MazeConfigError(
                f"{r.checkpoint} is not a maze {want} reward (family {rew.metadata.get('family')!r}, "
                f"method {getattr(rew, 'method', 'drs')!r}): reward.name must match the phase-1 run's"
            )
        if want != r.name:  # gail_stages: the stage term added to a GAIL checkpoint (Appendix F.2)
            rew.classifier_weight, rew.stage_weight = float(c.classifier_weight), float(c.stage_weight)
        return None, rew.requires_grad_(False)
    # the SAC families' settings of the method (conf/reward/<name>.yaml): every step costs (log D <= 0, D - 1 <= 0)
    use_action = bool(entry.get("use_action", False)) if c.use_action is None else bool(c.use_action)
    output, offset, trains_on = str(entry.output), float(entry.offset), entry.trains_on
    rew = ClassifierReward(
        ["observation"],
        {"observation": OBS_DIMS[cfg.coords]},
        1,
        use_action=use_action,
        action_dim=len(ACTIONS) if use_action else None,
        output=output,
        offset=offset,
        hidden=list(c.hidden),
        activation=c.activation,
        method=r.name,
        metadata={
            "family": FAMILY,
            "map": map_name,
            "reward_on": "state_action" if use_action else "next_state",
            "coords": cfg.coords,
            "seed": int(cfg.seed),
        },
    )
    common = dict(
        lr=float(c.lr),
        batch_size=int(c.batch_size),
        reward_updates_per_update=float(cfg[cfg.agent].reward_updates_per_update),
    )
    s_eps = demo_episodes(map_name, int(cfg.demos), int(cfg.seed), cfg.coords)  # observations of s ...
    n_eps = demo_episodes(map_name, int(cfg.demos), int(cfg.seed), cfg.coords, next_state=True)  # ... and of s'
    if trains_on == "success_states":  # the oracle's success label for every visited state; demos' goals seed them
        goals = (
            torch.stack([n.get(("next", "observation"))[-1] for n in n_eps])
            if n_eps
            else torch.zeros(0, OBS_DIMS[cfg.coords])
        )
        return SuccessClassifierLearner(
            rew,
            success_key="success",
            capacity=int(c.buffer_size),
            success_states=TensorDict({"observation": goals}, batch_size=[len(goals)]),
            **common,
        ), rew
    demos = [
        TensorDict(
            {
                "observation": n.get(("next", "observation")),
                "action": s.get(("next", "action")),
                "state": TensorDict({"observation": s.get(("next", "observation"))}, batch_size=s.shape),
            },
            batch_size=s.shape,
        )
        for s, n in zip(s_eps, n_eps)
    ]
    if trains_on == "demos_vs_random":  # demonstration states vs random-walk states, offline (prepare())
        return OfflineClassifierLearner(
            rew,
            demos=[d.select("observation") for d in demos],
            capacity=int(c.buffer_size),
            random_episodes=int(c.random_episodes),
            offline_updates=int(c.offline_updates),
            **common,
        ), rew
    return DemoDiscriminatorLearner(rew, demos=demos, **common), rew


def make_replay_buffer(cfg: DictConfig, drs: DrSReward | None) -> ReplayBuffer:
    """n-step windows (TorchRL's ``MultiStepTransform``) over a ``(T, envs)`` storage, or single steps
    whose DrS reward is recomputed from the current discriminator at every sample (Algorithm 1)."""
    d = cfg.dqn
    if int(d.n_steps) > 1:
        return ReplayBuffer(
            storage=LazyTensorStorage(int(d.buffer_size), ndim=2),
            batch_size=int(d.batch_size),
            transform=MultiStepTransform(int(d.n_steps), float(d.gamma)),
        )
    scale = float(d.get("reward_scale", 1.0))
    return ReplayBuffer(
        storage=LazyTensorStorage(int(d.buffer_size)),
        batch_size=int(d.batch_size),
        transform=reward_transform(drs, cfg.coords, scale) if drs is not None else None,
    )


# ----------------------------------------------------------------------------- the algorithm
def algo_config(cfg: DictConfig) -> DictConfig:
    """The settings of the run's agent: ``cfg.dqn`` (``agent=dqn``) or ``cfg.ppo`` (``agent=ppo``)."""
    return cfg.ppo if cfg.get("agent", "dqn") == "ppo" else cfg.dqn


def make_updater(cfg: DictConfig, env, drs, learn: bool):
    """The run's :class:`~drs_torchrl.updaters.base.Updater`: DQN (the paper's maze agent) or PPO."""
    if cfg.get("agent", "dqn") == "ppo":  # conf/algo/ppo.yaml's updater at ppo, built as drs-learn builds it
        # phase 1: the batch's reward from the discriminator of the moment (the env's is the collection-time one)
        scale = float(cfg.ppo.get("reward_scale", 1.0))
        return instantiate(cfg.ppo.updater)(
            env, reward=reward_transform(drs, cfg.coords, scale) if (learn and drs) else None
        )
    # conf/maze.yaml's dqn.updater; the app adds the replay buffer (single steps or n-step windows) and the annealing
    # length (a fraction of the run)
    d = cfg.dqn
    return instantiate(d.updater)(
        env,
        make_replay_buffer(cfg, drs),
        eps_anneal_steps=int(float(d.eps_anneal_frac) * int(cfg.total_frames)),
        n_step=int(d.n_steps) > 1,
    )


class _MazeLearner:
    """The reward learner as the loop sees it: DrS's stage buffers file the (s, a) pairs of each finished episode
    (:func:`sa_trajectory`); GAIL draws the agent's (s, a, s') from a flat buffer of its own (the DQN's holds n-step
    windows); everything else goes to the learner as it is."""

    def __init__(self, learner, cfg: DictConfig, drs):
        self.inner, self.cfg, self.drs = learner, cfg, drs
        self.agent_rb = None
        if isinstance(learner, DemoDiscriminatorLearner):
            self.agent_rb = ReplayBuffer(storage=LazyTensorStorage(int(cfg.reward.classifier.buffer_size)))
            learner.attach(self.agent_rb)

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def observe(self, batch, episodes) -> None:
        if self.agent_rb is not None:
            self.agent_rb.extend(batch.reshape(-1).select("observation", "action", ("next", "observation")))
        if isinstance(self.inner, DrSLearner):  # Algorithm 1: every finished episode into the stage buffers
            rc, on_next = reward_coords(self.drs), reads_next_state(self.drs)
            episodes = [
                sa_trajectory(ep, obs_coords=self.cfg.coords, reward_coords=rc, next_state=on_next) for ep in episodes
            ]
        self.inner.observe(batch, episodes)

    def update(self):
        return self.inner.update()


# ----------------------------------------------------------------------------- training
def train(cfg: DictConfig, run_dir: str | os.PathLike, resume: bool = False) -> dict:
    """Phase 1 or phase 2 (or a baseline) of the maze experiment, through the loop of Algorithm 1
    (:func:`drs_torchrl.loop.run_algorithm1`); writes into ``run_dir``. ``resume``: continue the run in ``run_dir``
    from the training state it saved when a signal stopped it (``cfg`` is its saved config, see :func:`resume_config`)."""
    validate(cfg)
    run_dir = Path(run_dir)
    torch.set_num_threads(int(cfg.num_threads))
    torch.manual_seed(int(cfg.seed))
    np.random.seed(int(cfg.seed))
    learn, a = cfg.phase == "learn", algo_config(cfg)
    ppo = cfg.get("agent", "dqn") == "ppo"
    map_name = cfg.map or ("train" if learn else "test")
    if resume:
        find_training_state(run_dir)  # fail before building anything
    learner, drs = make_reward(cfg, map_name, learn, resume)
    if not resume:
        # the run directory is written only once the reward (and its checkpoint) is known to be usable; a run it
        # replaces (overwrite=true) is set aside until this one's config is written
        old = check_run_dir(run_dir, bool(cfg.get("overwrite", False)))
        try:
            run_dir.mkdir(parents=True, exist_ok=True)
            OmegaConf.save(cfg, run_dir / "config.yaml", resolve=True)
        except BaseException:
            old.restore()
            raise
        replaced(run_dir, old)  # the old run's files go; this run's Hydra record becomes the directory's .hydra
    scale = float(a.get("reward_scale", 1.0))
    # the env writes R(s, a) where the agent does not recompute it: n-step sums (formed when transitions are
    # stored) and PPO's batches (see the module docstring)
    in_env = drs if (int(cfg.dqn.n_steps) > 1 or ppo) else None
    env = make_env(
        map_name, cfg.num_envs, cfg.max_steps, cfg.seed, cfg.reward.name, cfg.coords, in_env,
        float(cfg.reward.dense_coef), scale,
    )  # fmt: skip
    eval_env = make_env(map_name, cfg.eval.episodes, cfg.max_steps, cfg.seed + 10_000, cfg.reward.name, cfg.coords)
    updater = make_updater(cfg, env, drs, learn)
    episodes = EpisodeWindow(100, 1, lambda ep: ep.get(("next", "reward")))
    wrapped = _MazeLearner(learner, cfg, drs) if learner is not None else None
    progress, earlier = Progress(), {"wall_s": 0.0, "cpu_s": 0.0}
    # the training state (policy, optimiser, replay buffer, stage buffers, counters, RNG), as drs-learn's: written
    # only when a signal stops the run before its budget (a finished maze run keeps none: it takes minutes)
    state = _MazeState(run_dir, cfg.phase, updater, learner, wrapped, episodes, progress)
    if resume:
        earlier = state.load()
        env.set_seed(int(cfg.seed) + 1 + progress.frames)  # fresh episodes, not the first process's
        OmegaConf.save(cfg, run_dir / "config.yaml", resolve=True)  # with this process's total_frames
    collector = Collector(
        env,
        updater.policy,
        frames_per_batch=int(a.frames_per_batch),
        total_frames=int(cfg.total_frames) - progress.frames,
        auto_register_policy_transforms=False,
    )
    record = _MazeRecord(
        RunLogger(
            run_dir,
            tensorboard=bool(cfg.get("tensorboard", True)),
            csv_files=True,
            resume_step=progress.frames if resume else None,
        ),
        learner,
        getattr(updater, "explore", None),
        bool(cfg.verbose),
        ("loss_objective", "loss_critic") if ppo else ("dqn_loss",),
        earlier=earlier,
        rows=_logged_rows(run_dir / "train.csv") if resume else (),
    )
    state.record = record

    def evaluate() -> dict[str, float]:
        window = episodes.row()
        return {
            **evaluate_greedy(updater.eval_policy, eval_env),
            "train_success": window.get("success_rate", float("nan")),
            "train_length": window.get("episode_length", float("nan")),
        }

    def save() -> dict[str, str]:
        policy = updater.policy_checkpoint()["qnet"] if not ppo else updater.actor.state_dict()
        if progress.frames < int(cfg.total_frames) and cfg.get("save_state", True):  # stopped by a signal early
            state.save(policy)  # what a resume needs
        torch.save(policy, run_dir / "policy.pt")
        return {"policy": str(run_dir / "policy.pt")}

    try:
        if learner is not None and not resume:
            learner.prepare(env)  # ORIL: random-walk episodes and the offline fit, before the first step
        if not resume:
            record.log("eval", 0, evaluate())  # the untrained agent: every curve starts at 0 env steps
        interval = int(cfg.eval.interval)
        summary = run_algorithm1(
            collector,
            updater,
            learner=wrapped,
            episodes=episodes,
            logger=record,
            evaluate=evaluate,
            save=save,
            # evaluation and training statistics share the row; the training state only when stopped early (save)
            schedule=Schedule(int(cfg.total_frames), interval, interval, checkpoint_interval=10**12),
            progress=progress,
            name="drs-maze",
            progress_bar=False,
        )
    finally:
        collector.shutdown()
        record.close()
    if summary["interrupted"]:  # the training state is saved: drs-maze resume=RUN_DIR continues (no summary.json)
        return summary
    summary["resumed_from"] = progress.resumed_from
    out = _finish(cfg, run_dir, summary, record, map_name, drs, learner, updater)
    state.remove()  # finished: the state an earlier interruption left is not needed any more
    return out


class _MazeState:
    """A maze run's training state through drs-learn's :class:`~drs_torchrl.runtime.checkpoint.Checkpointer`
    (``RUN_DIR/checkpoints/state``): the agent (``updater.state_dict()``), its replay buffer, the reward learner
    and its buffers (GAIL's own buffer of the agent's transitions too), the loop's counters, the recent episodes and
    the RNG states."""

    def __init__(
        self, run_dir: Path, phase: str, updater, learner, wrapped, episodes: EpisodeWindow, progress: Progress
    ):
        self.run_dir, self.phase, self.updater, self.learner = run_dir, phase, updater, learner
        self.episodes, self.progress = episodes, progress
        self.buffers = dict(updater.buffers)
        if wrapped is not None and wrapped.agent_rb is not None:
            self.buffers["agent_transitions"] = wrapped.agent_rb
        self.record = None

    def _checkpointer(self) -> Checkpointer:
        return Checkpointer(self.run_dir, self.buffers, self.learner)  # (makes checkpoints/ only when used)

    def save(self, policy) -> None:
        ck = self._checkpointer()
        payload = ck.loop_state(
            self.phase, self.updater, self.progress, self.episodes,
            wall_s=self.record.wall_s(), cpu_s=self.record.cpu_s(),
        )  # fmt: skip
        ck.check_room([policy], payload)
        ck.save_state(payload)

    def load(self) -> dict:
        """Restore everything from the newest complete state; returns the earlier processes' wall and CPU seconds."""
        c = self._checkpointer().restore_loop_state(self.phase, self.updater, self.progress, self.episodes)
        return {"wall_s": float(c["wall_s"]), "cpu_s": float(c["cpu_s"])}

    def remove(self) -> None:
        shutil.rmtree(self.run_dir / "checkpoints", ignore_errors=True)


def _logged_rows(path: Path) -> list[dict]:
    """The rows an earlier process of a resumed run wrote to ``train.csv`` (numbers as floats)."""
    with path.open(newline="") as f:
        return [{k: float(v) if v not in ("", None) else float("nan") for k, v in r.items()} for r in csv.DictReader(f)]


class _MazeRecord:
    """The maze run's ``train.csv`` (and TensorBoard under ``tb/``): one row per greedy evaluation, holding the
    evaluation, the training success, epsilon, and the update and discriminator statistics the loop logged since
    the previous row (the loop's train rows come at the same env steps and are folded into it)."""

    def __init__(
        self, logger: RunLogger, learner, explore, verbose: bool, loss_keys=("dqn_loss",), earlier=None, rows=()
    ):
        self.logger, self.learner, self.explore, self.verbose = logger, learner, explore, verbose
        self.loss_keys = tuple(loss_keys)
        self.pending: dict = {}
        self.rows: list[dict] = list(rows)  # a resumed run: the earlier processes' rows
        self.t0, self.cpu0 = time.perf_counter(), time.process_time()
        self.earlier = earlier or {"wall_s": 0.0, "cpu_s": 0.0}  # the earlier processes' seconds

    def wall_s(self) -> float:
        """The run's wall-clock seconds so far, its earlier processes included."""
        return self.earlier["wall_s"] + time.perf_counter() - self.t0

    def cpu_s(self) -> float:
        return self.earlier["cpu_s"] + time.process_time() - self.cpu0

    def log(self, stream: str, frames: int, row: dict) -> None:
        if stream == "train":
            self.pending = row
            return
        p, nan = self.pending, float("nan")
        out = {
            "frames": frames,
            "wall_s": round(self.wall_s(), 2),
            "updates": int(p.get("updates", self.rows[-1]["updates"] if self.rows else 0)),
            "epsilon": float(self.explore.eps) if self.explore is not None else nan,
            **row,
            **{k: p.get(k, nan) for k in self.loss_keys},
            "reward_mean": p.get("reward_mean", nan),
        }
        if isinstance(self.learner, DrSLearner):
            counts = self.learner.stage_buffers.stage_counts()
            out.update(
                success_buffer=int(counts[1]),
                failure_buffer=int(counts[0]),
                disc_active=float(self.learner.loss.training_mask()[0]),
            )
        elif self.learner is not None:
            out.update(self.learner.log_row())
        if self.learner is not None:  # DrS: per-stage keys (one stage here); a classifier: loss and accuracy
            out["disc_updates"] = self.learner.updates
            out["disc_loss"] = p.get("disc_loss_0", p.get("disc_loss", nan))
            out["disc_accuracy"] = p.get("disc_accuracy_0", p.get("disc_accuracy", nan))
        self.pending = {}
        self.logger.log("train", frames, out)
        self.rows.append(out)
        if self.verbose:
            print(
                f"[{out['wall_s']:7.1f}s] frames {frames:7d}  eval success {out['eval_success']:.2f}  train success "
                f"{out['train_success']:.2f}  eps {out['epsilon']:.2f}",
                flush=True,
            )

    def flush(self) -> None:
        self.logger.flush()

    def close(self) -> None:
        self.logger.close()


def _finish(cfg, run_dir: Path, loop_summary: dict, record: _MazeRecord, map_name: str, drs, learner, updater) -> dict:
    """``summary.json``, the reward checkpoint and its figure."""
    rows, wall = record.rows, record.wall_s()
    summary = {
        "phase": cfg.phase,
        "map": map_name,
        "reward": cfg.reward.name,
        "algo": updater.name,
        "reward_scale": float(algo_config(cfg).get("reward_scale", 1.0)),
        "seed": int(cfg.seed),
        "code": code_version(),
        "reward_input": ("next_state" if reads_next_state(drs) else "state_action") if drs is not None else None,
        "reward_alpha": getattr(drs, "alpha", None),
        "reward_coords": reward_coords(drs) if (drs is not None and reward_coords(drs) != cfg.coords) else None,
        "frames": loop_summary["frames"],
        "resumed_from": loop_summary.get("resumed_from"),  # env steps where this process took over (None: from 0)
        "updates": updater.updates,
        "wall_time_s": round(wall, 1),
        "cpu_time_s": round(record.cpu_s(), 1),
        "env_steps_per_s": round(loop_summary["frames"] / wall, 1),
        "interrupted": loop_summary["interrupted"],
        "final_eval_success": rows[-1]["eval_success"],
        "final_eval_length": rows[-1]["eval_length"],
        "mean_eval_success_last3": float(np.mean([r["eval_success"] for r in rows[-3:]])),
    }
    if learner is not None:
        summary["reward_checkpoint"] = str(drs.save(run_dir / "reward.pt"))
        summary["disc_updates"] = learner.updates
        if isinstance(learner, DrSLearner):
            summary["stage_buffer_counts"] = learner.stage_buffers.stage_counts().tolist()
        else:
            summary.update(learner.summary())
    if drs is not None:
        maps = ("train", map_name if map_name != "train" else "test")
        summary["reward_map"] = str(plot_reward_map(drs, run_dir / "reward_map.png", tuple(cfg.plot_goal), maps))
        summary["reward_diagnostics"] = {m: reward_diagnostics(drs, m, cfg.max_steps) for m in GATES}
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary


# ----------------------------------------------------------------------------- CLI
RESUME_SETTINGS = ("total_frames", "verbose", "tensorboard", "num_threads")  # what a resume may change


def resume_config(run_dir: Path, overrides: list[str], composed: DictConfig) -> DictConfig:
    """The saved config of the maze run in ``run_dir``, with this invocation's :data:`RESUME_SETTINGS` overrides
    (values as Hydra parsed them into ``composed``); any other override is refused: the run's weights and buffers
    were made with its saved settings."""
    if not (run_dir / "config.yaml").is_file():
        raise MazeConfigError(f"cannot resume: {run_dir} holds no maze run (no config.yaml)")
    if maze_run_message(run_dir) is None:
        raise MazeConfigError(f"cannot resume: {run_dir} is not a drs-maze run; resume it with drs-learn/drs-reuse")
    if (run_dir / "summary.json").is_file():
        raise MazeConfigError(
            f"cannot resume: {run_dir} finished (summary.json) and a finished maze run keeps no training state; "
            "start a new run (another hydra.run.dir) for more env steps"
        )
    try:
        saved = load_run_config(run_dir, needs=("phase", "dqn", "reward"))
    except RunFileError as exc:
        raise MazeConfigError(f"cannot resume: {exc}") from None
    for o in overrides:
        key, _, value = o.partition("=")
        key = key.lstrip("+~")
        if key == "resume" or key.startswith("hydra.") or (key == "phase" and value == saved.phase):
            continue  # (drs-learn/drs-reuse env=maze resume=... name the phase)
        if key not in RESUME_SETTINGS:
            raise MazeConfigError(
                f"cannot change {key} of a maze run being resumed (its weights and buffers were made with its saved "
                f"settings; a resume takes {', '.join(RESUME_SETTINGS)}); start a new run instead"
            )
        OmegaConf.update(saved, key, OmegaConf.select(composed, key), merge=True)
    saved.resume = str(run_dir)
    return saved


@console_script("drs-maze")  # DRS_LIBRARY_MESSAGES=1 shows TorchRL's storage notices again
@hydra.main(config_path=conf_dir(), config_name="maze", version_base=None)
def main(cfg: DictConfig) -> None:
    """``drs-maze phase=learn|reuse|report ...`` or ``drs-maze resume=RUN_DIR`` (see conf/maze.yaml)."""
    run_dir = hydra_dir = HydraConfig.get().runtime.output_dir
    resume = bool(cfg.get("resume")) and cfg.phase != "report"
    record = current_record(run_dir) if cfg.phase != "report" else None  # Hydra's (a resume's: beside the run's)
    try:
        overrides = list(HydraConfig.get().overrides.task)
        if "env" in cfg or "map" not in cfg:  # env=OTHER (a family of drs-learn's) or ~env
            raise MazeConfigError(
                "drs-maze runs the maze family (conf/env/maze.yaml): leave env= out; its env settings are map=, "
                "num_envs=, max_steps=, coords= (other families: drs-learn env=NAME)"
            )
        check_added_settings(cfg, overrides, "maze", "maze", MazeConfigError)
        if cfg.phase != "report" and not resume and empty_run_dir():
            raise MazeConfigError(EMPTY_RUN_DIR)
        if cfg.phase == "report":
            res = report(cfg.report.root, cfg.report.out)
            print(f"drs-maze: report of {res['runs']} runs in {res['out']}")
            return
        if resume:
            run_dir = str(Path(cfg.resume))
            if Path(hydra_dir).resolve() != Path(run_dir).resolve():  # hydra.run.dir beside resume=: not written to
                unlock_run_dir(hydra_dir, remove_if_empty=True)
        lock_run_dir(run_dir, "choose another hydra.run.dir")  # the one writer of the run directory
        if resume:
            cfg = resume_config(Path(run_dir), overrides, cfg)
        s = train(cfg, run_dir, resume=resume)
    except (MazeConfigError, ValueError, FileNotFoundError, RunDirBusyError, TrainingStateError) as exc:
        print(f"drs-maze: error: {exc}", file=sys.stderr)
        if cfg.phase != "report":  # the refused run leaves the directory as it was (no Hydra record over a run's)
            discard_refused_record(record, resume=resume, locked=not resume)
            unlock_run_dir(run_dir, remove_if_empty=True)
        sys.exit(2)
    if s.get("interrupted"):
        saved = f"the training state is saved: continue with drs-maze resume={run_dir}"
        print(
            f"drs-maze: interrupted at {s['frames']} env steps; "
            + (saved if cfg.get("save_state", True) else "no training state saved (save_state=false)"),
            file=sys.stderr,
        )
        sys.exit(128 + int(s.get("signal", 2)))
    print(
        f"drs-maze: {s['phase']} on the {s['map']} map with the {s['reward']} reward: {s['frames']} env steps in "
        f"{s['wall_time_s']:.0f}s; greedy eval success {s['final_eval_success']:.2f}; run dir {run_dir}"
    )
    if "reward_checkpoint" in s:
        print(f"  reward checkpoint: {s['reward_checkpoint']}")


if __name__ == "__main__":
    main()
