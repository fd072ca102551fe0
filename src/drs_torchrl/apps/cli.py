"""Hydra entry points: ``drs-learn`` (phase 1, reward learning) and ``drs-reuse`` (phase 2).

Configs live in the repository's ``conf/`` (or ``$DRS_CONF_DIR``). Examples::

    drs-learn env=pick_cube algo=sac_cpu total_frames=200000 seed=3
    drs-reuse reward=drs reward.checkpoint=runs/learn/.../checkpoints/reward.pt env.split=test
    drs-reuse reward=dense env.split=test
    drs-learn resume=runs/learn/pick_cube/drs/<run>          # continue an interrupted run
    drs-learn resume=runs/learn/pick_cube/drs/<run> total_frames=2000000   # ... and extend it
"""

from __future__ import annotations

import errno
import functools
import signal
import sys
from pathlib import Path

import hydra
import yaml
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf, open_dict

from drs_torchrl.apps.hydra_record import (  # noqa: F401 (registers the configs' resolvers)
    EMPTY_RUN_DIR,
    RUN_MARKERS,
    current_record,
    discard_refused_record,
    empty_run_dir,
    holds_run,
    replaced,
)
from drs_torchrl.apps.reward_registry import with_builders
from drs_torchrl.config_dir import RENAMED_SETTINGS, renamed_hint
from drs_torchrl.config_dir import conf_dir  # noqa: F401 (the CLI's config path; re-exported)
from drs_torchrl.runtime.console import UserError, console_script, user_error_message
from drs_torchrl.runtime.errors import ConfigError
from drs_torchrl.runtime.rundir import (
    OldRun,
    clear_for_new_run,
    DiskFullError,
    RunFileError,
    load_run_config,
    maze_run_message,
    lock_run_dir,
    unlock_run_dir,
)

GROUPS = ("env", "reward", "algo", "logger")


class ResumeError(UserError, ValueError):
    """``resume=RUN_DIR`` that cannot be honoured."""


# settings that fix the shapes or the meaning of a run's saved state (network sizes, buffer capacities, the stages
# and the reward's inputs): a resumed run keeps them (its weights and buffers were made with them)
FIXED_ON_RESUME = (
    "algo.hidden",
    "algo.buffer_size",
    "reward.hidden",
    "reward.activation",
    "reward.in_keys",
    "reward.formula",
    "reward.stage_buffer_size",
    "reward.buffer_size",
    "reward.disc.window",
    "env.stages",
    "env.task_observation",
    "env.family",
    "env.env_id",
    "env.stage_keys",
    "env.control_mode",
    "algo.policy_in_keys",
    "algo.loss.num_qvalue_nets",
)


def resume_config(run_dir: Path, phase: str, overrides: list[str], composed: DictConfig | None = None) -> DictConfig:
    """The saved config of ``run_dir`` with this invocation's value overrides applied on top
    (values as Hydra parsed them into ``composed``, when given)."""
    saved_path = run_dir / "config.yaml"
    if not saved_path.is_file():
        raise ResumeError(f"cannot resume: {run_dir} is not a drs-torchrl run directory (no config.yaml)")
    try:
        saved = load_run_config(run_dir, needs=("phase",))
    except RunFileError as exc:
        raise ResumeError(f"cannot resume: {exc}") from None
    if maze := maze_run_message(run_dir):  # drs-maze resumes its own runs
        raise ResumeError(f"cannot resume: {maze}; continue it with drs-maze resume={run_dir}")
    if saved.get("phase") != phase:
        raise ResumeError(f"{run_dir} is a drs-{saved.get('phase')} run; resume it with drs-{saved.get('phase')}")
    rename_settings(saved)
    for o in overrides:
        key, _, value = o.partition("=")
        adding = key.startswith("+") and not key.startswith("++")
        key = key.lstrip("+~")
        if key == "resume" or key.startswith("hydra."):
            continue
        if key in GROUPS:
            raise ResumeError(f"cannot switch config group {key!r} of a run being resumed; start a new run instead")
        if OmegaConf.select(saved, key, default="__missing__") == "__missing__":
            parent = key.rpartition(".")[0]
            # "+key=value" may add an entry to a free-form mapping the run has (e.g. env.variant_overrides);
            # a key this version's config has and the run's lacks (added since the run started) is taken
            newer = composed is not None and OmegaConf.select(composed, key, default="__missing__") != "__missing__"
            if not (
                newer or (adding and parent and isinstance(OmegaConf.select(saved, parent, default=None), DictConfig))
            ):
                raise ResumeError(f"override {key!r} does not exist in the config of {run_dir}{renamed_hint(key)}")
        parsed = OmegaConf.select(composed, key) if composed is not None else yaml.safe_load(value)
        was = OmegaConf.select(saved, key, default=None)
        was = OmegaConf.to_container(was) if OmegaConf.is_config(was) else was
        now = OmegaConf.to_container(parsed) if OmegaConf.is_config(parsed) else parsed
        if key == "reward.checkpoint" and now != was and _other_reward(was, now):
            raise ResumeError(
                f"cannot change reward.checkpoint of a run being resumed to a different reward (its replay buffer "
                f"holds rewards of {was}); start a new run with reward.checkpoint={value} instead"
            )
        if key in FIXED_ON_RESUME and now != was:
            raise ResumeError(
                f"cannot change {key} of a run being resumed (its saved weights and buffers were made with "
                f"{key}={was}); start a new run with {key}={value} instead"
            )
        OmegaConf.update(saved, key, parsed, merge=True)
    saved.resume = str(run_dir)
    if "reward" in saved:
        with_builders(saved.reward)  # saved before the reward registry named its builders
    if "algo" in saved and saved.algo.get("updater") is None:  # written by the code before 0.1.0, never released
        raise ResumeError(
            f"cannot resume: {run_dir}/config.yaml predates drs-torchrl 0.1.0 (no algo.updater); start a new run "
            "(its checkpoints/reward.pt and policy.pt still load)"
        )
    return saved


def rename_settings(saved: DictConfig) -> None:
    """A saved config's settings under their current names (:data:`~drs_torchrl.config_dir.RENAMED_SETTINGS`): a run
    saved by 0.1.0 resumes with its value under the new key. In place."""
    for old, new in RENAMED_SETTINGS.items():
        value = OmegaConf.select(saved, old, default="__missing__")
        if value == "__missing__":
            continue
        parent, _, leaf = old.rpartition(".")
        with open_dict(saved):
            OmegaConf.update(saved, new, value, merge=False, force_add=True)
            del OmegaConf.select(saved, parent)[leaf]


def _other_reward(was, now) -> bool:
    """A reward checkpoint path that names a different reward: the saved one still exists and its bytes differ (a
    file moved to another path, the old one gone, is taken as the same reward)."""
    from drs_torchrl.tools.study import sha256_file

    if not was or not now:
        return bool(was) != bool(now)
    if not Path(str(was)).is_file() or not Path(str(now)).is_file():  # moved; a missing new one is named on loading
        return False
    return sha256_file(was) != sha256_file(now)


class ExistingRunError(UserError, ValueError):
    """A fresh run pointed at a directory that already holds one."""


def check_fresh_run_dir(run_dir: Path, phase: str, overwrite: bool) -> OldRun:
    """Refuse to start a new run in ``run_dir`` when it holds a run, unless ``overwrite``: then that run's files
    are set aside (returned), so the new run's logs and checkpoints are not mixed with them; the caller passes
    them to :func:`replaced` once the new run has started, or restores them."""
    return clear_for_new_run(
        run_dir,
        RUN_MARKERS,
        overwrite,
        error=ExistingRunError,
        options=f"continue it with drs-{phase} resume={run_dir}, choose another hydra.run.dir",
    )


def check_reused_reward_overrides(cfg: DictConfig, phase: str, overrides: list[str]) -> None:
    """Refuse a ``reward.formula`` / ``alpha`` / ``offset`` / ``hidden`` / ``activation`` / ``in_keys`` override of
    drs-reuse that is not what its ``reward.checkpoint`` was learned with: a reused reward is the frozen one as it
    was learned (the run would silently use the checkpoint's and its config.yaml would say otherwise)."""
    from drs_torchrl.rewards import FROZEN_SETTINGS, differs, frozen_settings
    from drs_torchrl.transforms.reward import load_reward

    given = {
        k[len("reward.") :] for k in (o.partition("=")[0].lstrip("+~") for o in overrides) if k.startswith("reward.")
    }
    keys = [k for k in FROZEN_SETTINGS if k in given]
    if phase != "reuse" or not keys or not cfg.reward.get("checkpoint"):
        return
    have = frozen_settings(load_reward(cfg.reward.checkpoint))
    bad = [k for k in keys if k in have and differs(cfg.reward.get(k), have[k])]
    if bad:
        given = ", ".join(f"reward.{k}={cfg.reward.get(k)}" for k in bad)
        learned = ", ".join(f"{k}={have[k]}" for k in bad)
        raise ConfigError(
            f"{given} is not what {cfg.reward.checkpoint} was learned with ({learned}); a reused reward is used as it "
            "was learned: drop the override, or learn a reward with it in drs-learn"
        )


def _run(cfg: DictConfig, phase: str) -> None:
    from drs_torchrl.runtime.console import library_messages_requested, quiet_libraries

    if not library_messages_requested(cfg):
        quiet_libraries()
    from drs_torchrl.updaters.base import NonFiniteError
    from drs_torchrl.apps.build import Run

    run_dir = HydraConfig.get().runtime.output_dir
    record = current_record(run_dir)
    locked, runner, old = [], None, None
    try:
        resume = bool(cfg.get("resume"))
        if resume:
            run_dir = str(Path(cfg.resume))
        elif empty_run_dir():
            raise ConfigError(EMPTY_RUN_DIR)
        # the one writer of the run directory (Hydra's record is already beside another writer's: the resolver locked)
        locked.append(lock_run_dir(run_dir, "choose another hydra.run.dir"))
        from drs_torchrl.tasks import family_from_config
        from drs_torchrl.apps.overrides import check_added_settings
        from drs_torchrl.apps.validation import validate_config

        overrides = list(HydraConfig.get().overrides.task)
        if resume:
            cfg = resume_config(Path(run_dir), phase, overrides, composed=cfg)
        validate_config(cfg, phase, resume)  # a refused setting (overwrite=no too) touches no run
        family_from_config(cfg.env)
        if not resume:  # (a resume's overrides are checked against the run's config by resume_config)
            check_added_settings(cfg, overrides, phase, phase)
            check_reused_reward_overrides(cfg, phase, overrides)
            old = check_fresh_run_dir(Path(run_dir), phase, bool(cfg.get("overwrite", False)))
        runner = Run(cfg, phase, run_dir, resume=resume)
        if old is not None:
            replaced(Path(run_dir), old)  # the new run is built and has written its config: the old one goes
            old = None
        summary = runner.run()
    except NonFiniteError as exc:
        print(f"drs-{phase}: stopped: {exc}", file=sys.stderr)
        sys.exit(3)
    except Exception as exc:  # noqa: BLE001 (a bug is re-raised for the console wrapper to report)
        msg = _user_message(exc, cfg, phase, run_dir, training=runner is not None and runner.training)
        if msg is None:
            raise
        print(f"drs-{phase}: error: {msg}", file=sys.stderr)
        # a failed resume leaves the run as it was, a refused new run no folder (a full disk: its resume record stays)
        discard_refused_record(record, resume=resume, locked=bool(locked), keep_side_record=_disk_full(exc))
        if old:  # the new run did not start: the run it was to replace is put back
            old.restore()
        for d in locked:  # a directory made for this run that holds nothing else goes too
            unlock_run_dir(d, remove_if_empty=True)
        sys.exit(2)
    finally:
        if old:  # interrupted before the new run started: the run it was to replace is put back
            old.restore()
        for d in locked:
            unlock_run_dir(d)  # the next job of a Hydra multirun may write here
    ev = summary.get("last_eval", {})
    print(
        f"drs-{phase}: {summary['frames']} env steps, {summary['updates']} {summary.get('algo', 'sac').upper()} updates in "
        f"{summary['wall_time_s']:.0f}s ({summary['env_steps_per_s']:.1f} steps/s); "
        f"eval success {ev.get('success_rate', float('nan')):.2f}; run dir {run_dir}"
    )
    for name, path in summary.get("checkpoints", {}).items():
        print(f"  {name} checkpoint: {path}")
    if summary.get("interrupted"):
        # non-zero, as shells expect (130 SIGINT, 143 SIGTERM): "drs-learn ... && drs-reuse ..." stops here
        print(
            f"drs-{phase}: interrupted at {summary['frames']} env steps; continue with: drs-{phase} resume={run_dir}",
            file=sys.stderr,
        )
        sys.exit(128 + int(summary.get("signal", signal.SIGINT)))


def _disk_full(exc: Exception) -> bool:
    return isinstance(exc, DiskFullError) or (isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT))


def _user_message(exc: Exception, cfg: DictConfig, phase: str, run_dir, training: bool = False) -> str | None:
    """The one line for an error the user can fix, else None (a bug: the console wrapper reports it). While the
    run is built, the config layer's KeyError/ValueError name a setting; once ``training``, they are bugs."""
    msg = user_error_message(exc)
    if _disk_full(exc):  # mid-run: what was saved is kept
        state = Path(run_dir) / "checkpoints" / "state" / "COMPLETE"
        if state.is_file():
            return f"{msg}; the training state at {state.read_text()} env steps is kept: continue with drs-{phase} resume={run_dir}"
        return f"{msg}; no training state was saved yet"
    if msg is not None and msg.startswith("gymnasium:") and OmegaConf.select(cfg, "env.env_id", default=None):
        return f"env.env_id={cfg.env.env_id}: {msg}"
    if msg is None and not training and isinstance(exc, (KeyError, ValueError)):
        msg = str(exc.args[0] if isinstance(exc, KeyError) and exc.args else exc)
    return msg


class MazeFamilyError(UserError, ValueError):
    """``drs-learn env=maze`` with an override the maze family does not take."""


MAZE_ALGOS = ("dqn", "ppo")


def maze_arguments(args: list[str], phase: str) -> list[str] | None:
    """``drs-learn env=maze ...`` / ``drs-reuse env=maze ...`` as the ``drs-maze`` arguments that run it, or None
    when ``args`` do not name the maze.

    The maze is a family of the same loop of Algorithm 1 (``tasks/maze.py`` holds its pieces: the batched grid
    env, the (s, a) reward, the shortest-path demonstrations; ``apps/maze.py`` wires them) with its own config,
    ``conf/maze.yaml`` (its env settings ``conf/env/maze.yaml``): its env, reward input and agents share no setting
    with the ManiSkill families' groups. So ``algo=dqn|ppo`` becomes ``agent=``, ``reward=NAME`` becomes
    ``reward.name=NAME``, and the other overrides (``resume=RUN_DIR`` too) are ``conf/maze.yaml``'s."""
    if "env=maze" not in args:
        return None
    out = [f"phase={phase}"]
    for a in args:
        key, _, value = a.partition("=")
        if a == "env=maze":
            continue
        if key == "algo":
            if value not in MAZE_ALGOS:
                raise MazeFamilyError(f"env=maze runs algo=dqn (the paper's maze agent) or algo=ppo, got algo={value}")
            out.append(f"agent={value}")
        elif key == "reward":
            out.append(f"reward.name={value}")
        elif key in ("init_from", "phase") or key.startswith(("env.", "algo.")):
            raise MazeFamilyError(
                f"env=maze does not take {key}=: its settings are conf/maze.yaml's (e.g. dqn.lr=..., "
                "map=test_shift3); see drs-maze --help"
            )
        else:
            out.append(a)
    return out


def _maze_or(main, phase: str):
    """``main``, unless the arguments name ``env=maze``: then ``drs-maze`` runs them (see :func:`maze_arguments`)."""

    @functools.wraps(main)
    def dispatch():
        try:
            args = maze_arguments(sys.argv[1:], phase)
        except MazeFamilyError as exc:
            print(f"drs-{phase}: error: {exc}", file=sys.stderr)
            sys.exit(2)
        if args is None:
            return main()
        from drs_torchrl.apps import maze

        sys.argv = [sys.argv[0], *args]
        return maze.main()

    return dispatch


@console_script("drs-learn", quiet=False)
@hydra.main(config_path=conf_dir(), config_name="learn", version_base=None)
def _learn(cfg: DictConfig) -> None:
    _run(cfg, "learn")


@console_script("drs-reuse", quiet=False)
@hydra.main(config_path=conf_dir(), config_name="reuse", version_base=None)
def _reuse(cfg: DictConfig) -> None:
    _run(cfg, "reuse")


learn_main = _maze_or(_learn, "learn")
learn_main.__doc__ = """Phase 1: SAC (or ``algo=ppo``) on the training variants, stage buffers, per-stage
discriminators; ``env=maze algo=dqn`` runs the maze family."""
reuse_main = _maze_or(_reuse, "reuse")
reuse_main.__doc__ = """Phase 2: a fresh agent on held-out variants with a frozen reward (or a baseline);
``env=maze`` runs the maze family."""
