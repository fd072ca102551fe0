"""``drs-study``: many drs-learn / drs-reuse runs from one YAML file, K at a time, re-invocable.

A study file names its runs (a ``grid`` of overrides and/or an explicit ``runs`` list); every
invocation starts what has not started, resumes (``resume=DIR``) what was interrupted, and skips
what has finished, so the same command is re-run across sessions until the study is done::

    drs-study results/precision/study.yaml --jobs 2          # both cores, one torch thread per run
    drs-study results/precision/study.yaml --status          # what is done, what is left
    drs-study results/precision/study.yaml --check           # every run's config composed and validated, nothing run
    drs-study results/precision/study.yaml --report results/precision   # the record to commit (below)
    drs-study results/precision/study.yaml --executor slurm   # each run a Slurm job through submitit (below)

Study file::

    root: runs/precision                 # run directories: <root>/<run name>
    app: learn                           # learn | reuse (per run: app:)
    common: [env=turn_valve, total_frames=120000, eval.episodes=10]
    grid: {algo.precision: [fp32, bf16], seed: [0, 1]}     # run names like precision-bf16_seed-1
    runs:                                # optional extra runs; needs: runs that must finish first
      - {name: reuse-drs-s0, app: reuse, args: [reward=drs, reward.checkpoint=<reward:learn-s0>], needs: [learn-s0]}
    record: results/precision            # optional: the folder --report writes (see below)
    figures:                             # optional: curated comparisons, --report writes OUT/figures/<name>/
      main: {title: "reuse on held-out variants", groups: [drs, sparse], labels: {drs: DrS}}

``<root>`` in an argument is the run root; ``<reward:NAME>`` and ``<policy:NAME>`` are phase-1 run NAME's
reward and policy checkpoints (``<root>/NAME/checkpoints/reward.pt``, or the committed
``<record>/run_files/NAME/reward.pt`` when the run directory is gone; ``policy.pt`` alike, for
``init_from=``, fine-tuning).

Run directories hold training states, which are not committed; a study that spans machines or fresh
checkouts names its ``record``: a run whose directory is absent but whose committed record there
(``run_files/NAME/summary.json``) says it finished is ``recorded``, skipped like a finished run, and
satisfies ``needs``.

A run is finished when its ``summary.json`` says it was not interrupted and it reached its
``total_frames`` (its own, or the study file's if that is larger: raising it there extends finished
runs). SIGINT/SIGTERM to the study stop every run at its next batch boundary (each
saves its training state) and the study exits 130/143; re-invoke it to continue.
(Hydra's multirun launchers start every job afresh and know neither resuming nor skipping.)

``--executor slurm`` (``submitit-local``: the same on one machine) submits each run as a submitit job instead of a
child process, with the study file's ``cluster:`` section (``partition``, ``time_min``, ``cpus_per_task``,
``mem_gb``, ``gpus``, ``max_jobs``, ``max_resubmits``, ``signal_delay_s``, ``setup``, ``slurm_additional``; the
command line overrides them). The jobs outlive the call: each is recorded in ``<root>/logs/<run>.job.json``, a call
started again follows the jobs still queued or running, and a run whose job ended before it finished is resubmitted
with ``resume=`` (:mod:`drs_torchrl.tools.study_cluster`, ``docs/cluster.md``).

``--report OUT`` reads the run directories (finished, interrupted or still running; a run without one
keeps the record OUT already holds) and writes
what a results folder commits, never training states: ``OUT/run_files/<run>/`` (``train.csv``,
``eval.csv``, ``config.yaml``, ``summary.json``; a phase-1 run's ``reward.pt`` and ``policy.pt`` too; a reuse run's
``reward.json``, below), ``OUT/status.md``
(each run's state, env steps and last evaluation, and the run-hours left), and ``drs-compare`` of the finished phase-2 runs into
``OUT/`` and of the finished phase-1 runs into ``OUT/learn/`` (a run still going would cut every curve's
horizon), grouped by run name without its seed (``drs_s0``, ``drs_s1`` -> ``drs``). A study with many groups
also names ``figures``: each compares the listed groups only, in that order (so their colours), with the given
display labels and title, into ``OUT/figures/<name>/`` (``compare.png/.csv/.md``).

A reuse run's ``config.yaml`` names the reward it reused where the run found it, often a run directory
(``runs/...``) that exists on one machine only. Its record therefore also gets ``reward.json``::

    {"checkpoint": "results/reuse/pick_cube/run_files/learn-placed_5cm_s0/reward.pt",   # committed, repo-relative
     "sha256": "…",                                                                     # of that file
     "ran_with": "runs/reuse_pick_cube/learn-placed_5cm_s0/checkpoints/reward.pt"}       # config.yaml's, unchanged

the committed copy of that reward (the phase-1 run's ``OUT/run_files/NAME/reward.pt`` when it is a run of the study,
else the file itself when it lies outside the run root) pinned by hash; ``drs-eval`` loads the reward from there and
refuses a file whose hash differs. ``config.yaml`` stays as the run composed it.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import os
import re
import shutil
import signal
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from drs_torchrl.tools.study_cluster import (
    EXECUTORS,
    SubmititRuns,
    Submitted,
    describe_jobs,
    ended,
    failures_in_a_row,
    job_file,
    last_job_states,
    live_job,
    parse_cluster,
    read_jobs,
    write_jobs,
)
from drs_torchrl.runtime.console import at_least, console_script
from drs_torchrl.runtime.errors import UserError


class StudyError(UserError, ValueError):
    """A study file that cannot be run."""


@dataclass
class Run:
    name: str
    app: str
    args: list[str]
    needs: list[str] = field(default_factory=list)


DONE = ("finished", "recorded")
_CHECKPOINT_REF = re.compile(r"<(reward|policy):([^>]+)>")


def _short(key: str) -> str:
    return key.split(".")[-1]


def _safe(value) -> str:
    """A value as part of a directory name Hydra accepts in an override (no ``,=/`` or spaces)."""
    return re.sub(r"[^A-Za-z0-9.+-]", "-", str(value))


def load_study(path: str | Path) -> tuple[Path, list[Run]]:
    """(root, runs) of a study file; raises :class:`StudyError` naming what is wrong."""
    path = Path(path)
    if not path.is_file():
        raise StudyError(f"study file {path} does not exist")
    try:
        spec = yaml.safe_load(path.read_text()) or {}
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise StudyError(f"{path} is not a YAML study file ({type(exc).__name__})") from None
    if not isinstance(spec, dict) or "root" not in spec:
        raise StudyError(f"{path}: a study file is a mapping with at least 'root' and 'grid' or 'runs'")
    allowed = ("root", "app", "common", "grid", "runs", "description", "record", "figures", "cluster")
    unknown = set(spec) - set(allowed)
    if unknown:
        raise StudyError(f"{path}: unknown keys {sorted(unknown)} (allowed: {', '.join(allowed)})")
    root = Path(spec["root"])
    app = spec.get("app", "learn")
    common = [str(a) for a in _listed(path, "common", spec.get("common"))]
    runs: list[Run] = []
    grid = spec.get("grid") or {}
    if grid:
        keys = list(grid)
        for values in itertools.product(*(grid[k] if isinstance(grid[k], list) else [grid[k]] for k in keys)):
            name = "_".join(f"{_short(k)}-{_safe(v)}" for k, v in zip(keys, values))
            runs.append(Run(name, app, [*common, *(f"{k}={_override_value(v)}" for k, v in zip(keys, values))]))
    for r in _listed(path, "runs", spec.get("runs")):
        if not isinstance(r, dict) or "name" not in r:
            raise StudyError(f"{path}: every entry of 'runs' needs a name, got {r!r}")
        unknown = set(r) - {"name", "app", "args", "needs"}
        if unknown:
            raise StudyError(
                f"{path}: run {r['name']}: unknown keys {sorted(unknown)} (allowed: name, app, args, needs)"
            )
        args = [str(a).replace("<root>", str(root)) for a in _listed(path, f"run {r['name']}: args", r.get("args"))]
        needs = [str(n) for n in _listed(path, f"run {r['name']}: needs", r.get("needs"))]
        runs.append(Run(str(r["name"]), r.get("app", app), [*common, *args], needs))
    if not runs:
        raise StudyError(f"{path}: no runs (give a 'grid' or a 'runs' list)")
    names = [r.name for r in runs]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise StudyError(f"{path}: run names {dup} appear twice")
    same: dict[tuple, str] = {}
    for r in runs:  # a copy-paste slip (the seed left unchanged) would pass for a second seed of the same setting
        settings = dict(a.partition("=")[::2] for a in r.args)  # Hydra's order: a later override wins
        twin = same.setdefault((r.app, frozenset(settings.items())), r.name)
        if twin != r.name:
            raise StudyError(
                f"{path}: runs {twin} and {r.name} have the same app and settings, so they would train the same "
                "run twice; give one of them another seed (seed=N) or remove it"
            )
    for r in runs:
        if r.app not in ("learn", "reuse"):
            raise StudyError(f"{path}: run {r.name}: app must be learn or reuse, got {r.app!r}")
        missing = [n for n in r.needs if n not in names]
        if missing:
            raise StudyError(f"{path}: run {r.name} needs {missing}, which the study does not define")
        for kind, ref in (m for a in r.args for m in _CHECKPOINT_REF.findall(a)):
            if ref not in r.needs:
                raise StudyError(f"{path}: run {r.name} uses <{kind}:{ref}> but does not list {ref} in its needs")
    _parse_figures(path, spec.get("figures"), runs)
    _parse_cluster(path, spec.get("cluster"))
    return root, runs


def _parse_cluster(path: Path, spec):
    try:
        return parse_cluster(spec)
    except ValueError as exc:
        raise StudyError(f"{path}: cluster: {exc}") from None


def load_cluster(path: str | Path):
    """The study file's ``cluster:`` section (:class:`~drs_torchrl.tools.study_cluster.Cluster`; defaults if absent)."""
    return _parse_cluster(Path(path), (yaml.safe_load(Path(path).read_text()) or {}).get("cluster"))


def _listed(path: Path, what: str, value) -> list:
    """A study file's list (absent: empty); a string where a list belongs would be read letter by letter."""
    if value is None:
        return []
    if not isinstance(value, list):
        raise StudyError(f"{path}: {what} must be a list, e.g. [{value!r}], got {type(value).__name__} {value!r}")
    return value


def _override_value(v) -> str:
    """A grid value as Hydra reads it back: YAML's null and booleans as null / true / false."""
    return "null" if v is None else str(v).lower() if isinstance(v, bool) else str(v)


@dataclass
class Figure:
    """A curated comparison of some of a study's groups (run names without their seeds)."""

    name: str
    groups: list[str]
    title: str = ""
    labels: dict[str, str] = field(default_factory=dict)


def _parse_figures(path: Path, spec, runs: list[Run]) -> list[Figure]:
    if spec is None:
        return []
    if not isinstance(spec, dict):
        raise StudyError(f"{path}: 'figures' maps a figure name to {{groups: [...], title: ..., labels: {{...}}}}")
    known = list(dict.fromkeys(group_name(r.name) for r in runs))
    figures = []
    for name, fig in spec.items():
        if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]*", str(name)):
            raise StudyError(f"{path}: figure name {name!r} is not a plain folder name (letters, digits, _ . -)")
        if not isinstance(fig, dict) or not isinstance(fig.get("groups"), list) or not fig["groups"]:
            raise StudyError(f"{path}: figure {name}: give a non-empty 'groups' list (run names without their seeds)")
        bad = set(fig) - {"groups", "title", "labels"}
        if bad:
            raise StudyError(f"{path}: figure {name}: unknown keys {sorted(bad)} (allowed: groups, title, labels)")
        groups = [str(g) for g in fig["groups"]]
        unknown = [g for g in groups if g not in known]
        if unknown:
            raise StudyError(
                f"{path}: figure {name}: groups {unknown} name no run of the study (its groups: {', '.join(known)})"
            )
        labels = {str(k): str(v) for k, v in (fig.get("labels") or {}).items()}
        stray = [k for k in labels if k not in groups]
        if stray:
            raise StudyError(f"{path}: figure {name}: labels for {stray}, which are not among its groups")
        shown = [labels.get(g, g) for g in groups]
        if len(set(shown)) < len(shown):
            raise StudyError(f"{path}: figure {name}: two groups would be drawn as one (labels {shown})")
        figures.append(Figure(str(name), groups, str(fig.get("title") or ""), labels))
    return figures


def load_figures(path: str | Path) -> list[Figure]:
    """The study file's ``figures`` (validated against its runs), in file order."""
    _, runs = load_study(path)
    return _parse_figures(Path(path), (yaml.safe_load(Path(path).read_text()) or {}).get("figures"), runs)


def load_record(path: str | Path) -> Path | None:
    """The study file's ``record`` folder, or None."""
    spec = yaml.safe_load(Path(path).read_text()) or {}
    return Path(spec["record"]) if spec.get("record") else None


def pid_file(root: Path, name: str) -> Path:
    """Where a study writes the process id of the run it started (``ROOT/logs/NAME.pid``)."""
    return root / "logs" / f"{name}.pid"


def running_pid(root: Path, name: str) -> int | None:
    """The live process training run ``name`` under ``root``, started by some ``drs-study`` call, or ``None``.

    Written because two study calls on one root (say ``--only a`` and a plain call) would otherwise
    restart, and first delete, a run the other is training."""
    try:
        pid = int(pid_file(root, name).read_text().split()[0])
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace")
    except (OSError, ValueError, IndexError):
        return None
    # a recycled pid runs something else: the run's own command names its directory
    return pid if str(root / name) in cmdline.replace("\0", " ") else None


def _live_job(root: Path, name: str) -> str | None:
    """``"slurm job 1234"`` while a submitit job of a study call trains run ``name`` (its job file), else None."""
    return live_job(root, name) if job_file(root, name).is_file() else None


def _locked(run_dir: Path) -> bool:
    """Some process holds the run directory's lock (it writes the run)."""
    from drs_torchrl.runtime.rundir import RunDirBusyError, lock_run_dir, unlock_run_dir

    if not run_dir.is_dir():
        return False
    try:
        lock_run_dir(run_dir)
    except RunDirBusyError:
        return True
    unlock_run_dir(run_dir)
    return False


def _written_elsewhere(root: Path, name: str) -> bool:
    """Run ``name`` is trained by a live process now: one a study call started (its pid file), or any process that
    holds the run directory's lock (a ``drs-learn`` started by hand there). Asked just before a run is (re)started
    or a broken one deleted, since another call may have started it after this one read the states."""
    return running_pid(root, name) is not None or _live_job(root, name) is not None or _locked(root / name)


def study_state(root: Path, record: Path | None, run: Run) -> str:
    """:func:`run_state` of the run's directory, ``running`` while another study call trains it; where
    there is none, ``recorded`` if the committed record says the run finished (its state is gone: a fresh
    checkout), else ``new``."""
    if running_pid(root, run.name) is not None or _live_job(root, run.name) is not None:
        return "running"
    state = run_state(root / run.name, wanted_frames(run))
    if (
        state == "new"
        and record is not None
        and run_state(record / "run_files" / run.name, wanted_frames(run)) == "finished"
    ):
        return "recorded"
    return state


def resolve_args(run: Run, root: Path, record: Path | None) -> list[str]:
    """The run's arguments with ``<reward:NAME>`` / ``<policy:NAME>`` replaced by NAME's checkpoint:
    its run directory's, else the record's."""

    def where(m: re.Match) -> str:
        file = f"{m.group(1)}.pt"
        live = root / m.group(2) / "checkpoints" / file
        kept = record / "run_files" / m.group(2) / file if record is not None else None
        return str(kept if not live.is_file() and kept is not None and kept.is_file() else live)

    return [_CHECKPOINT_REF.sub(where, a) for a in run.args]


_FILE_ARGS = ("demos.path", "reward.checkpoint", "init_from")


def check_run(run: Run, root: Path, record: Path | None) -> str | None:
    """Compose ``run``'s config as ``drs-<app>`` would and validate it, without starting it: the
    problem in one line, or None. Catches a bad override or a missing file before hours are queued
    behind it (a checkpoint another run of the study will write is not required to exist yet)."""
    from hydra import compose, initialize_config_dir
    from hydra.errors import HydraException
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    from drs_torchrl.tasks import family_from_config
    from drs_torchrl.apps import cli as apps  # noqa: F401  (registers the resolvers the configs use)
    from drs_torchrl.runtime.errors import ConfigError
    from drs_torchrl.apps.overrides import check_added_settings
    from drs_torchrl.rewards import is_learned, reward_setup
    from drs_torchrl.apps.validation import validate_config

    args = resolve_args(run, root, record)
    for raw, arg in zip(run.args, args):
        key, _, value = arg.partition("=")
        key = key.lstrip("+")
        if key not in _FILE_ARGS or value in ("", "null") or Path(value).exists() or _CHECKPOINT_REF.search(raw):
            continue
        if not any(
            Path(value).resolve().is_relative_to((root / n).resolve()) for n in run.needs
        ):  # else a need writes it
            hint = {
                "demos.path": f"record them first: drs-demos --family FAMILY --out {value}",
                "reward.checkpoint": "a reward.pt written by drs-learn",
                "init_from": "the directory of a finished drs-learn run",
            }
            return f"{key}={value}: no such file ({hint[key]})"
    try:
        with initialize_config_dir(config_dir=apps.conf_dir(), version_base=None):
            cfg = compose(config_name=run.app, overrides=args)
            check_added_settings(cfg, args, run.app, run.app)
        validate_config(cfg, run.app)
        if not is_learned(cfg.reward):  # a static reward's slot reads no file: build it (a checkpoint it would ignore)
            reward_setup(cfg.reward, run.app)
        family = family_from_config(cfg.env)
        split = str(cfg.env.get("split") or "train")
        family.env_args(split, OmegaConf.to_container(cfg.env.get("variant_overrides") or OmegaConf.create({})))
    except (HydraException, OmegaConfBaseException, ConfigError, KeyError, ValueError) as exc:
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        return " ".join(str(msg).split()).split(" Config search path")[0]
    return None


def wanted_frames(run: Run) -> int | None:
    """The ``total_frames`` a study asks of a run (the last ``total_frames=`` of its arguments), or None."""
    values = [a.split("=", 1)[1] for a in run.args if a.split("=", 1)[0] == "total_frames"]
    try:
        return int(values[-1]) if values else None
    except ValueError:
        return None


def run_state(run_dir: Path, want_frames: int | None = None) -> str:
    """``finished``, ``resumable`` (a complete training state), ``broken`` (a directory with no
    usable state: it is started again) or ``new``. A run that finished short of ``want_frames``
    (the study file now asks for more) is ``resumable``; one that stopped at ``stop_at_success`` or
    ``eval.stop_at_success`` is finished."""
    summary = run_dir / "summary.json"
    if summary.is_file():
        try:
            s = json.loads(summary.read_text())
            import omegaconf

            total = int(omegaconf.OmegaConf.load(run_dir / "config.yaml").total_frames)
            total = max(total, want_frames or 0)
            early = s.get("stopped_at_success") or s.get("stopped_at_eval_success")
            if not s.get("interrupted") and (int(s.get("frames", 0)) >= total or early):
                return "finished"
        except Exception:
            pass
    ck = run_dir / "checkpoints"
    if (ck / "state" / "COMPLETE").is_file() or (ck / "state.old" / "COMPLETE").is_file():
        return "resumable"
    return "broken" if run_dir.exists() else "new"


def command(run: Run, run_dir: Path, state: str, args: list[str] | None = None) -> list[str]:
    exe = str(Path(sys.executable).parent / f"drs-{run.app}")
    args = run.args if args is None else args
    if state == "resumable":
        # budget overrides (a larger total_frames, the stopping rules) are honoured on resume
        budget = ("total_frames", "stop_at_success", "eval.stop_at_success", "eval.stop_streak")
        extend = [a for a in args if a.split("=", 1)[0].lstrip("+") in budget]
        return [exe, f"resume={run_dir}", *extend]
    return [exe, *args, f"hydra.run.dir={run_dir}"]


RECORD_FILES = ("train.csv", "eval.csv", "config.yaml", "summary.json")
REWARD_PIN = "reward.json"


class RecordError(UserError, ValueError):
    """A committed record whose pinned reward is missing or is not the file it pinned."""


def sha256_file(path: str | Path) -> str:
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _repo_path(path: Path) -> str:
    """``path`` relative to the working directory (the repository root, where studies run) when inside it."""
    path = path.resolve()
    return str(path.relative_to(Path.cwd().resolve())) if path.is_relative_to(Path.cwd().resolve()) else str(path)


def pin_reward(record_dir: Path, committed: Path | None, ran_with: str, note: str = "") -> Path:
    """Write ``record_dir/reward.json``: the committed reward file a reuse record reused and its sha256
    (``committed=None``: the reward was not committed, ``note`` says so)."""
    pin = {
        "checkpoint": _repo_path(committed) if committed is not None else None,
        "sha256": sha256_file(committed) if committed is not None else None,
        "ran_with": ran_with,
    }
    if note:
        pin["note"] = note
    (record_dir / REWARD_PIN).write_text(json.dumps(pin, indent=1) + "\n")
    return record_dir / REWARD_PIN


def pinned_reward(run_dir: str | Path) -> Path | None:
    """The reward file a record pins in ``reward.json``, its hash checked; None where it pins none (a run
    directory, a record of a run that reused no learned reward). The pinned path is repository-relative: it
    is looked up from the record's folder upwards, so the record evaluates from any working directory."""
    run_dir = Path(run_dir)
    f = run_dir / REWARD_PIN
    if not f.is_file():
        return None
    try:
        pin = json.loads(f.read_text())
        checkpoint, digest = pin["checkpoint"], pin["sha256"]
    except (ValueError, KeyError, TypeError):
        raise RecordError(f"{f} is not a reward pin (a JSON object with checkpoint and sha256)") from None
    if checkpoint is None:
        raise RecordError(
            f"{run_dir}: the reward this run reused ({pin.get('ran_with')}) was not committed"
            + (f": {pin['note']}" if pin.get("note") else "")
        )
    rel = Path(checkpoint)
    where = (
        [rel] if rel.is_absolute() else [a / rel for a in (run_dir.resolve(), *run_dir.resolve().parents, Path.cwd())]
    )
    found = next((w for w in where if w.is_file()), None)
    if found is None:
        raise RecordError(f"{f} pins {checkpoint}, which is not in this checkout")
    if sha256_file(found) != digest:
        raise RecordError(
            f"{found} is not the reward {f} pins (sha256 differs): the record's reward was changed or replaced"
        )
    return found


def _pin_reuse_record(dst: Path, root: Path, files: Path) -> None:
    """Pin the reward a freshly copied reuse record reused (``reward.json``), or say why it cannot be."""
    try:
        cfg = yaml.safe_load((dst / "config.yaml").read_text()) or {}
        used = (cfg.get("reward") or {}).get("checkpoint") if cfg.get("phase") == "reuse" else None
    except (OSError, yaml.YAMLError, AttributeError):
        return
    if not used:
        return
    live = Path(str(used)).resolve()
    committed = None
    if live.is_relative_to(root.resolve()):  # a run of the study: its record's copy
        name = live.relative_to(root.resolve()).parts[0]
        committed = files / name / "reward.pt"
    elif live.is_file():  # a committed reward (or any file outside the run root), named as it is
        committed = live
    if committed is None or not committed.is_file():
        print(
            f"drs-study: report: {dst.name} reused {used}, which the record does not hold: its reward.json is "
            f"not written (commit that reward and pin it so that the record evaluates elsewhere)",
            file=sys.stderr,
        )
        return
    if live.is_file() and live != committed.resolve() and sha256_file(live) != sha256_file(committed):
        print(
            f"drs-study: report: {dst.name} reused {used}, which differs from {committed}: not pinned", file=sys.stderr
        )
        return
    pin_reward(dst, committed, str(used))


def group_name(run_name: str) -> str:
    """A run's name without its seed: ``drs_s0`` / ``seed-1`` suffixes, and a grid's ``seed-1`` part
    anywhere (``seed-0_precision-bf16``), name the seed, not the method."""
    name = re.sub(r"[_-](s|seed-)\d+$", "", run_name)
    name = "_".join(part for part in name.split("_") if not re.fullmatch(r"seed-\d+", part))
    return name or run_name


def _copy_record(src: Path, dst: Path) -> None:
    """A text record with this checkout's absolute path removed, so the copy reads the same anywhere."""
    text = src.read_text()
    dst.write_text(text.replace(str(Path.cwd().resolve()) + os.sep, ""))


def _last_eval(run_dir: Path) -> str:
    f = run_dir / "eval.csv"
    lines = f.read_text().strip().splitlines() if f.is_file() else []
    if len(lines) < 2:
        return "-"
    head, last = lines[0].split(","), lines[-1].split(",")
    row = dict(zip(head, last))
    try:
        return f"{float(row['success_rate']):.2f} at {int(float(row['step']))}"
    except (KeyError, ValueError):
        return "-"


def _frames(run_dir: Path) -> int:
    f = run_dir / "train.csv"
    lines = f.read_text().strip().splitlines() if f.is_file() else []
    try:
        return int(float(lines[-1].split(",")[0])) if len(lines) > 1 else 0
    except ValueError:
        return 0


def _summary(run_dir: Path) -> dict:
    try:
        return json.loads((run_dir / "summary.json").read_text())
    except (OSError, ValueError):
        return {}


def _logged_speeds(run_dir: Path) -> list[float]:
    """Every positive ``env_steps_per_s`` a run directory's ``train.csv`` logged (one per log row), in order."""
    f = run_dir / "train.csv"
    lines = f.read_text().strip().splitlines() if f.is_file() else []
    if len(lines) < 2 or "env_steps_per_s" not in lines[0].split(","):
        return []
    col, out = lines[0].split(",").index("env_steps_per_s"), []
    for line in lines[1:]:
        try:
            v = float(line.split(",")[col])
        except (ValueError, IndexError):
            continue
        if v > 0:
            out.append(v)
    return out


# a run's first rows are its random warm-up, with no updates, several times its later speed (stack_cube dense_s1's
# train.csv: 283 and 256 env steps/s, then about 60), so a run directory's speed counts once it has logged this many
# rows; until then the record's finished runs say more
SPEED_ROWS = 5


def _duration(seconds: float) -> str:
    return f"{seconds / 3600:.1f} h" if seconds >= 3600 else f"{seconds / 60:.0f} min"


def work_left(root: Path, record: Path | None, runs: list[Run], states: dict[str, str], jobs: int = 2) -> str:
    """One line on what the study still costs: runs and env steps left, and the hours they take at the
    study's own measured speed: the median over the run directories on this machine of each one's median logged
    ``env_steps_per_s`` (their ``train.csv``, once a run has logged :data:`SPEED_ROWS` rows; a shorter finished run's
    ``summary.json``), else of the record's
    ``summary.json`` files (a fresh checkout: other machines), else the last rows of runs that have just started.

    Written because a study spans sessions and days; planning one needs its remaining run-hours."""
    logged = [_logged_speeds(root / r.name) for r in runs]
    speeds, where = [statistics.median_high(v) for v in logged if len(v) >= SPEED_ROWS], "run directories here"
    for r, v in zip(runs, logged):  # a short run that finished here: its summary's speed, not the warm-up fallback
        measured = _summary(root / r.name).get("env_steps_per_s") if states[r.name] in DONE else None
        if len(v) < SPEED_ROWS and isinstance(measured, (int, float)) and measured > 0:
            speeds.append(float(measured))
    if not speeds and record is not None:
        speeds = [_summary(record / "run_files" / r.name).get("env_steps_per_s") for r in runs]
        speeds, where = [float(v) for v in speeds if isinstance(v, (int, float)) and v > 0], "recorded runs"
    if not speeds:  # only runs that have just started: their warm-up rows overstate the speed
        speeds = [v[-1] for v in logged if v]
        where = f"run directories here, under {SPEED_ROWS} log rows each: warm-up runs faster, an upper bound"
    left = [r for r in runs if states[r.name] not in DONE]
    steps, unsized = 0, []
    for r in left:
        asked = wanted_frames(r)
        if asked is None:
            try:
                asked = int(yaml.safe_load((root / r.name / "config.yaml").read_text())["total_frames"])
            except (OSError, KeyError, TypeError, ValueError):
                unsized.append(r.name)
                continue
        done = _frames(root / r.name) if states[r.name] in ("resumable", "running") else 0
        steps += max(asked - done, 0)
    if not left:
        return f"left: nothing, all {len(runs)} runs done"
    early = any(r.app == "learn" for r in left)
    line = f"left: {len(left)} of {len(runs)} runs, {'at most ' if early else ''}{steps:,} env steps" + (
        " (phase-1 runs stop early at stop_at_success)" if early else ""
    )
    if unsized:
        line += f", not counting {len(unsized)} run(s) without a total_frames ({', '.join(unsized)})"
    if speeds:
        v = statistics.median_high(speeds)
        line += (
            f"; at {v:.1f} env steps/s per run (median of {len(speeds)} {where}) about "
            f"{_duration(steps / v)} of runs, {_duration(steps / v / max(jobs, 1))} with --jobs {max(jobs, 1)}"
        )
    else:
        line += "; no run has measured its speed yet"
    return line


def report(
    root: Path,
    runs: list[Run],
    out: Path,
    study_file: str | Path = "",
    record: Path | None = None,
    figures: list[Figure] | None = None,
) -> dict[str, Path]:
    """Copy each run's record into ``out/run_files``, write ``out/status.md`` and the comparisons (and each of
    ``figures`` into ``out/figures/<name>/``).

    A run with no directory under ``root`` keeps the record ``out`` (or the study's ``record``) already
    holds, so a report from a fresh checkout neither loses nor misstates what earlier sessions ran."""
    from drs_torchrl.tools.comparison import CompareError, compare

    out = Path(out)
    files = out / "run_files"
    files.mkdir(parents=True, exist_ok=True)
    rows = ["| run | app | state | env steps (asked) | last evaluation: success at step |", "|---|---|---|---|---|"]
    copied: dict[str, list[Path]] = {"reuse": [], "learn": []}
    for r in runs:
        run_dir, dst = root / r.name, files / r.name
        asked = wanted_frames(r)
        state = study_state(root, record, r)
        if (run_dir / "train.csv").is_file():
            dst.mkdir(exist_ok=True)
            for name in RECORD_FILES:
                if (run_dir / name).is_file():
                    _copy_record(run_dir / name, dst / name)
            for name in ("reward.pt", "policy.pt") if r.app == "learn" else ():  # for reuse and fine-tuning later
                if (run_dir / "checkpoints" / name).is_file():
                    shutil.copy2(run_dir / "checkpoints" / name, dst / name)
        elif state == "recorded" and (record / "run_files" / r.name).resolve() != dst.resolve():
            shutil.copytree(record / "run_files" / r.name, dst, dirs_exist_ok=True)
        shown = run_dir if (run_dir / "train.csv").is_file() else dst
        if state == "new" and (dst / "train.csv").is_file():
            state = "new (an unfinished earlier record)"  # its training state is gone: it starts again
        rows.append(
            f"| `{r.name}` | {r.app} | {state} | {_frames(shown):,} ({asked if asked else 'its default'}) | {_last_eval(shown)} |"
        )
        if (
            dst / "config.yaml"
        ).is_file() and state in DONE:  # the comparison: finished runs only (status.md has the rest)
            copied[r.app].append(dst)
    for r in runs:  # after every copy: a reuse run's reward is the record of a phase-1 run listed after it
        if r.app == "reuse" and (root / r.name / "train.csv").is_file() and (files / r.name / "config.yaml").is_file():
            _pin_reuse_record(files / r.name, root, files)
    paths = {"status": out / "status.md"}
    head = f"Written by `drs-study {study_file} --report {out}`; states as `drs-study --status` sees them.\n\n"
    states = {r.name: study_state(root, record, r) for r in runs}
    tail = "\n" + work_left(root, record, runs, states) + " (`drs-study --status` says the same).\n"
    paths["status"].write_text(head + "\n".join(rows) + "\n" + tail)
    # reuse runs on another split than most (e.g. the dense baseline checked on the training variants) get
    # their own comparison, so that the AUC horizon and the curves of the main one are the held-out runs'
    by_split: dict[str, list[Path]] = {}
    for d in copied["reuse"]:
        by_split.setdefault(_env_split(d), []).append(d)
    main_split = max(by_split, key=lambda k: len(by_split[k])) if by_split else None
    jobs = [(by_split.get(main_split, []), out, "reuse")]
    jobs += [(ds, out / f"on_{split}", f"reuse_on_{split}") for split, ds in by_split.items() if split != main_split]
    jobs.append((copied["learn"], out / "learn", "learn"))
    for dirs, where, key in jobs:
        if dirs:
            try:
                made = compare(dirs, where, labels=[group_name(d.name) for d in dirs])
            except CompareError as exc:
                print(f"drs-study: report: {key} runs not compared: {exc}", file=sys.stderr)
                continue
            paths.update({f"{key}_{k}": v for k, v in made.items()})
    finished: dict[str, list[Path]] = {}
    for d in copied["reuse"] + copied["learn"]:
        finished.setdefault(group_name(d.name), []).append(d)
    for fig in figures or []:
        dirs = [d for g in fig.groups for d in finished.get(g, [])]
        missing = [g for g in fig.groups if g not in finished]
        if missing:
            print(f"drs-study: report: figure {fig.name}: no finished runs yet for {missing}", file=sys.stderr)
        if not dirs:
            continue
        try:
            made = compare(
                dirs,
                out / "figures" / fig.name,
                title=fig.title,
                labels=[fig.labels.get(group_name(d.name), group_name(d.name)) for d in dirs],
            )
        except CompareError as exc:
            print(f"drs-study: report: figure {fig.name} not drawn: {exc}", file=sys.stderr)
            continue
        paths.update({f"figure_{fig.name}_{k}": v for k, v in made.items()})
    return paths


def _env_split(run_dir: Path) -> str:
    """The ``env.split`` a recorded run trained on (``config.yaml``), ``"-"`` where it names none."""
    cfg = yaml.safe_load((run_dir / "config.yaml").read_text()) or {}
    return str((cfg.get("env") or {}).get("split") or "-")


def _driver_lock(root: Path):
    """The one submitit driver of a run root: ``ROOT/logs/driver.lock``, open and flock-ed (held until it is
    closed), or, where another process holds it, that process's pid (a string)."""
    import fcntl

    (root / "logs").mkdir(parents=True, exist_ok=True)
    f = open(root / "logs" / "driver.lock", "a+")
    try:
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        f.seek(0)
        holder = f.read().strip() or "unknown"
        f.close()
        return holder
    f.seek(0)
    f.truncate()
    f.write(f"{os.getpid()}\n")
    f.flush()
    return f


def _cluster_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("clusters (--executor submitit-local | slurm; the study file's cluster: section)")
    g.add_argument(
        "--executor",
        choices=EXECUTORS,
        default="local",
        help="local: child processes of this call (default); submitit-local: submitit jobs on this machine; "
        "slurm: Slurm jobs through submitit. Jobs outlive this call: run it again to follow them",
    )
    g.add_argument("--partition", default=None, help="Slurm partition (cluster: partition)")
    g.add_argument("--time-min", type=at_least(1), default=None, help="each job's time limit in minutes")
    g.add_argument("--cpus-per-task", type=at_least(1), default=None, help="CPUs per job")
    g.add_argument("--mem-gb", type=float, default=None, help="memory per job in GB")
    g.add_argument("--gpus", type=at_least(0), default=None, help="GPUs per job; > 0 runs each run with device=cuda")
    g.add_argument("--max-jobs", type=at_least(1), default=None, help="jobs queued or running at once")
    g.add_argument(
        "--max-resubmits",
        type=at_least(0),
        default=None,
        help="jobs in a row that may end without the run saving progress before it is given up (default 3)",
    )
    g.add_argument(
        "--cancel", action="store_true", help="cancel the study's queued and running jobs (each run saves) and exit"
    )


@console_script("drs-study")
def main(argv: list[str] | None = None) -> int:
    with contextlib.ExitStack() as held:  # the driver lock of a submitit call, released on return
        return _main(argv, held)


def _main(argv: list[str] | None, held: contextlib.ExitStack) -> int:
    p = argparse.ArgumentParser(prog="drs-study", description=__doc__.split("\n")[0])
    p.add_argument("study", help="study YAML file")
    p.add_argument(
        "--jobs",
        "-j",
        type=at_least(1),
        default=2,
        help="runs side by side (default 2: one per core of a 2-core machine)",
    )
    p.add_argument(
        "--threads",
        type=at_least(1),
        default=None,
        help="torch threads per run (default 1; --executor slurm: the study's cpus_per_task)",
    )
    p.add_argument("--status", action="store_true", help="print each run's state and exit")
    p.add_argument("--only", nargs="*", default=None, help="run only these run names")
    p.add_argument(
        "--check",
        action="store_true",
        help="compose and validate every run's config (overrides, files, values) without running; exit 2 on a problem",
    )
    p.add_argument(
        "--report",
        type=Path,
        metavar="OUT",
        default=None,
        help="write the study's record (run files, status.md, drs-compare figures) into OUT and exit",
    )
    _cluster_args(p)
    a = p.parse_args(argv)
    try:
        root, runs = load_study(a.study)
        record = load_record(a.study)
        cluster = load_cluster(a.study)
        every = list(runs)  # --only narrows what runs, not what counts as done
    except StudyError as exc:
        print(f"drs-study: error: {exc}", file=sys.stderr)
        return 2
    for key in ("partition", "time_min", "cpus_per_task", "mem_gb", "gpus", "max_jobs", "max_resubmits"):
        if getattr(a, key) is not None:
            setattr(cluster, key, getattr(a, key))
    if a.mem_gb is not None and a.mem_gb <= 0:
        print(f"drs-study: error: --mem-gb must be positive, got {a.mem_gb}", file=sys.stderr)
        return 2
    threads = a.threads or (cluster.cpus_per_task if a.executor == "slurm" else None) or 1
    if a.only is not None:
        unknown = [n for n in a.only if n not in {r.name for r in runs}]
        if unknown:
            print(f"drs-study: error: --only names {unknown} that the study does not define", file=sys.stderr)
            return 2
        runs = [r for r in runs if r.name in a.only]
    want = {r.name: wanted_frames(r) for r in runs}
    last_jobs = last_job_states(root, [r.name for r in runs])  # their states asked at once (Slurm: one query)
    states = {r.name: study_state(root, record, r) for r in runs}
    if a.report is not None:
        if a.report.resolve() == root.resolve() or root.resolve() in a.report.resolve().parents:
            print(
                f"drs-study: error: --report {a.report} is inside the study's run root {root}: give a results folder",
                file=sys.stderr,
            )
            return 2
        for path in report(root, runs, a.report, a.study, record, load_figures(a.study)).values():
            print(path)
        return 0
    if a.status:
        notes = {n: describe_jobs(rec, st, cluster.max_resubmits) for n, (rec, st) in last_jobs.items()}
        for r in runs:
            print(f"{states[r.name]:>10}  {root / r.name}" + (f"  {notes[r.name]}" if r.name in notes else ""))
        print(work_left(root, record, runs, states, a.jobs))
        return 0
    jobs = None  # the submitit executors' driver side (None: the local executor, child processes)
    missing = [c for c in ("sbatch", "srun") if shutil.which(c) is None]
    if a.executor == "slurm" and missing and not a.check:
        print(
            f"drs-study: error: --executor slurm: no {' or '.join(missing)} here; run it where Slurm's commands are "
            "(a login node), or try the study on this machine with --executor submitit-local",
            file=sys.stderr,
        )
        return 2
    if (a.executor != "local" and not a.check) or a.cancel:
        lock = _driver_lock(root)
        if isinstance(lock, str):
            what = "cancel their jobs" if a.cancel else "follow the same jobs"
            print(
                f"drs-study: error: another drs-study call (pid {lock}) follows the jobs of {root}; stop it first "
                f"(Ctrl-C or kill {lock}: its jobs keep running), then {what}",
                file=sys.stderr,
            )
            return 2
        held.callback(lock.close)
        if a.cancel:
            cancelled = 0
            for r in runs:
                rec = read_jobs(root, r.name)
                which = SubmititRuns(rec["executor"], root, cluster).cancel(r.name) if rec is not None else None
                if which:
                    cancelled += 1
                    print(f"drs-study: {r.name}: {which} cancelled (the run saves its state)", flush=True)
            if not cancelled:
                print(f"drs-study: no job of {a.study} is queued or running", flush=True)
            return 0
        jobs = SubmititRuns(a.executor, root, cluster)
    busy = [r.name for r in runs if states[r.name] == "running"]
    active: dict = {}  # run name -> its child process (local) or the job followed (submitit)
    if jobs is not None:  # a driver started again: follow the jobs still queued or running, note those that ended
        for r in runs:
            rec = read_jobs(root, r.name)
            if rec is None:
                continue
            if rec.get("given_up") and states[r.name] not in DONE:
                print(f"drs-study: {r.name}: given up earlier ({rec['given_up']}); trying again", flush=True)
                rec.update(given_up=None, count_from=len(rec["jobs"]))
                write_jobs(root, r.name, rec)
            last = rec["jobs"][-1]
            if "ended" in last:
                continue
            sub = jobs.attach(r.name)
            if sub is not None or _locked(root / r.name):  # alive, or ended while its run still saves: wait for it
                active[r.name] = sub or Submitted(last["job_id"])
                print(f"drs-study: {r.name}: following {rec['executor']} job {last['job_id']}", flush=True)
            else:
                state = jobs.state(r.name, Submitted(last["job_id"]))
                jobs.close(r.name, state)
                print(
                    f"drs-study: {r.name}: {rec['executor']} job {last['job_id']} ended ({state}) while no study call "
                    f"followed it, {run_state(root / r.name, want[r.name])}",
                    flush=True,
                )
        states.update({r.name: study_state(root, record, r) for r in runs if r.name not in active})
        busy = [r.name for r in runs if states[r.name] == "running" and r.name not in active]
    for name in busy:
        pid = running_pid(root, name)
        who = f"pid {pid}" if pid is not None else _live_job(root, name)
        print(f"drs-study: {name}: being trained by another call ({who}), skipped", flush=True)
    pending = [r for r in runs if states[r.name] not in (*DONE, "running") and r.name not in active]
    problems = {r.name: check_run(r, root, record) for r in (runs if a.check else pending)}
    if a.check:
        for r in runs:
            print(
                f"{'ok' if problems[r.name] is None else 'error':>6}  {r.name}"
                + (f": {problems[r.name]}" if problems[r.name] else "")
            )
    bad = {n: p for n, p in problems.items() if p is not None}
    if bad:
        if not a.check:
            for n, p in bad.items():
                print(f"drs-study: error: run {n}: {p}", file=sys.stderr)
            print(
                f"drs-study: nothing started: fix {len(bad)} run(s) in {a.study} (or leave them out with --only)",
                file=sys.stderr,
            )
        return 2
    if a.check:
        return 0
    (root / "logs").mkdir(parents=True, exist_ok=True)
    for r in runs:
        if states[r.name] in DONE:
            print(f"drs-study: {r.name}: {states[r.name]}, skipped", flush=True)
    by_name = {r.name: r for r in runs}
    failed: list[str] = []
    stop = {"sig": None}
    if jobs is None:
        at_once = a.jobs
    else:
        at_once = cluster.max_jobs or (a.jobs if a.executor == "submitit-local" else len(runs))

    def on_signal(signum, frame):
        stop["sig"] = signum
        if jobs is None:
            for proc in active.values():
                proc.send_signal(signal.SIGTERM)  # each run saves at its next batch boundary

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    env = dict(os.environ, OMP_NUM_THREADS=str(threads), MKL_NUM_THREADS=str(threads))
    done = {r.name for r in every if study_state(root, record, r) in DONE}  # only this loop's runs change it
    try:
        while (pending or active) and stop["sig"] is None:
            if jobs is not None:
                jobs.refresh(list(active))
            for name, handle in list(active.items()):
                if jobs is None:
                    if handle.poll() is None:
                        continue
                    del active[name]
                    pid_file(root, name).unlink(missing_ok=True)
                    how, rec = f"exit {handle.returncode}", None
                else:
                    job_state = jobs.state(name, handle)
                    if not ended(job_state) or _locked(root / name):  # a job ended while its run saves: wait
                        continue
                    del active[name]
                    handle.job = None  # submitit's job object: not left for the interpreter's shutdown
                    rec = jobs.close(name, job_state)
                    how = f"{rec['executor']} job {handle.job_id} {job_state}"
                state = run_state(root / name, want[name])
                print(f"drs-study: {name}: {how}, {state}", flush=True)
                if state == "finished":
                    done.add(name)
                elif jobs is not None and _resubmit(jobs, name, rec, cluster.max_resubmits, root):
                    pending.insert(0, by_name[name])
                else:
                    failed.append(name)
            for r in list(pending):
                if len(active) >= at_once:
                    break
                if any(n in failed for n in r.needs):
                    pending.remove(r)
                    failed.append(r.name)
                    print(f"drs-study: {r.name}: not started, it needs {r.needs} and one of them failed", flush=True)
                    continue
                if not all(n in done for n in r.needs):
                    continue
                run_dir = root / r.name
                if _written_elsewhere(root, r.name):  # started since this call looked (another call, or by hand)
                    pending.remove(r)
                    busy.append(r.name)
                    print(f"drs-study: {r.name}: being trained by another process, skipped", flush=True)
                    continue
                state = run_state(run_dir, want[r.name])
                if state == "broken":  # started but never reached a checkpoint: nothing to keep
                    shutil.rmtree(run_dir)
                cmd = command(r, run_dir, state, resolve_args(r, root, record))
                if state != "resumable" and not any(c.startswith("torch_threads=") for c in cmd):
                    cmd.append(f"torch_threads={threads}")  # a resumed run keeps its own
                if jobs is not None and cluster.gpus:
                    cmd.append("device=cuda")
                log = open(root / "logs" / f"{r.name}.log", "a")
                log.write(f"\n# {time.strftime('%Y-%m-%d %H:%M:%S')} {' '.join(cmd)}\n")
                log.flush()
                verb = "resuming" if state == "resumable" else "starting"
                if jobs is None:
                    print(f"drs-study: {r.name}: {verb}", flush=True)
                    active[r.name] = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env)
                    pid_file(root, r.name).write_text(f"{active[r.name].pid}\n")
                else:
                    log.close()
                    extra = {"OMP_NUM_THREADS": str(threads), "MKL_NUM_THREADS": str(threads)}
                    active[r.name] = jobs.submit(r.name, cmd, root / "logs" / f"{r.name}.log", extra)
                    with open(root / "logs" / f"{r.name}.log", "a") as log:
                        log.write(f"# {a.executor} job {active[r.name].job_id} ({jobs.folder(r.name)})\n")
                    print(f"drs-study: {r.name}: {verb} ({a.executor} job {active[r.name].job_id})", flush=True)
                pending.remove(r)
            if pending and not active:
                waiting = [r.name for r in pending]
                print(f"drs-study: error: {waiting} wait for runs that are not in this invocation", file=sys.stderr)
                return 2
            time.sleep(2)
        if jobs is None:
            for proc in active.values():
                proc.wait()
    finally:
        for handle in active.values() if jobs is not None else ():
            handle.job = None
        for s, h in previous.items():
            signal.signal(s, h)
    if stop["sig"] is not None:
        if jobs is not None:
            left = ", ".join(f"{n} (job {h.job_id})" for n, h in active.items()) or "none"
            print(
                f"drs-study: stopped; the jobs keep going: {left}. Re-run the same command to follow them "
                "(--status shows them, --cancel stops them).",
                flush=True,
            )
            return 128 + stop["sig"]
        print("drs-study: stopped; every run saved its state. Re-run the same command to continue.", flush=True)
        return 128 + stop["sig"]
    if failed:
        print(f"drs-study: {len(failed)} run(s) did not finish: {failed} (see {root / 'logs'})", file=sys.stderr)
        return 1
    if busy:
        print(f"drs-study: {busy} still trained by another call: re-run this command once they end", flush=True)
        return 0
    print(f"drs-study: all {len(runs)} runs finished in {root}", flush=True)
    return 0


def _resubmit(jobs, name: str, rec: dict, max_resubmits: int, root: Path) -> bool:
    """Whether run ``name``, whose job ended before it finished, gets another job (it resumes from its saved state);
    no once ``max_resubmits`` jobs in a row ended without the run saving progress (a run that crashes at start)."""
    fails = failures_in_a_row(rec)
    if fails > max_resubmits:
        last = rec["jobs"][-1]
        why = (
            f"{fails} jobs in a row ended without the run saving progress (the last: {last['job_id']} {last['ended']})"
        )
        jobs.give_up(name, why)
        print(f"drs-study: {name}: given up: {why}; see {root / 'logs' / (name + '.log')}", flush=True)
        return False
    note = f" ({fails} of {max_resubmits} resubmissions without progress used)" if fails else ""
    print(f"drs-study: {name}: its job ended before the run finished: resubmitting{note}", flush=True)
    return True


if __name__ == "__main__":
    sys.exit(main())
