"""``drs-quickstart``: the README's first command, DrS learned and reused end to end in minutes.

On the paper's navigation family (the three-room maze of ``drs-maze``, Appendix "Navigation"):

1. phase 1 (Algorithm 1): a DQN explores the *train* map, its finished episodes fill the stage
   buffers, and the discriminator learns the reward; the reward is frozen into ``reward.pt``;
2. phase 2: fresh DQN agents train on the *test* map, whose two gates are swapped, one with the
   frozen DrS reward and one per baseline (sparse, semi-sparse by default);
3. a figure (``quickstart.png``: both phases' curves and the learned reward per cell) and a
   summary (printed, and in ``summary.json``).

Runs go ``jobs`` at a time (the baselines need no phase 1, so they start at once), each a
``drs-maze`` process with one torch thread, logging into ``<out>/logs/``. The console shows one
progress bar per running run. Re-running the same command continues: finished runs are kept and
unfinished ones start again (a maze run takes minutes; starting it again, rather than resuming its saved state,
keeps its result the uninterrupted run's).
SIGINT/SIGTERM stop the runs and exit 130/143. (``drs-study`` schedules the resumable SAC runs;
this is its small cousin for a fixed four-run plan with live progress and a summary.)
"""

from __future__ import annotations

import contextlib
import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from drs_torchrl.apps.overrides import check_added_settings
from drs_torchrl.runtime.console import UserError, console_script
from drs_torchrl.runtime.rundir import LOCK_NAME, RunDirBusyError, lock_run_dir, unlock_run_dir
from drs_torchrl.config_dir import conf_dir as _conf_dir

SUCCESS_BAR = 0.9  # "solved": greedy success at or above this
ESTIMATE = "7-17 min"  # measured: 16.4 min on a 2-core Ice Lake (results/quickstart/), ~7 on Sapphire Rapids
LABELS = {
    "drs": "DrS (frozen, reused)",
    "sparse": "sparse",
    "semi_sparse": "semi-sparse",
    "dense": "human-engineered dense",
}


class QuickstartError(UserError, ValueError):
    """A quickstart that cannot start, with the fix in its message."""


@dataclass
class Job:
    name: str  # run folder under <out>
    title: str  # what the progress bar says
    args: list[str]
    needs: list[str] = field(default_factory=list)


def plan(cfg: DictConfig, out: Path) -> list[Job]:
    """Phase 1 on the train map, then DrS and each baseline on the test map."""
    try:
        seed, frames, jobs = int(cfg.seed), int(cfg.total_frames), int(cfg.jobs)
    except (TypeError, ValueError):
        raise QuickstartError(
            f"seed, total_frames and jobs must be integers, got seed={cfg.seed!r}, "
            f"total_frames={cfg.total_frames!r}, jobs={cfg.jobs!r}"
        ) from None
    if frames <= 0 or jobs <= 0:
        raise QuickstartError(f"total_frames and jobs must be positive, got {frames} and {jobs}")
    if seed < 0:
        raise QuickstartError(f"seed must be >= 0 (it seeds numpy and the maze), got {seed}")
    for key in ("learn", "common", "extra"):
        if not OmegaConf.is_list(cfg[key]):
            raise QuickstartError(
                f"{key} must be a list of drs-maze overrides, e.g. {key}=[dqn.lr=0.001], got {cfg[key]!r}"
            )
    if not OmegaConf.is_list(cfg.baselines):
        raise QuickstartError(f"baselines must be a list, e.g. baselines=[sparse,semi_sparse], got {cfg.baselines!r}")
    if not OmegaConf.is_dict(cfg.reuse) or not all(OmegaConf.is_list(v) for v in cfg.reuse.values()):
        raise QuickstartError(
            "reuse maps each phase-2 reward to its drs-maze overrides (a list), as conf/quickstart.yaml"
        )
    unknown = [b for b in cfg.baselines if b not in cfg.reuse or b == "drs"]
    if unknown:
        raise QuickstartError(
            f"unknown baselines {unknown}; choose from {[k for k in cfg.reuse if k != 'drs']}, "
            f"e.g. baselines=[sparse,semi_sparse]"
        )
    common = [*map(str, cfg.common), f"seed={seed}", f"total_frames={frames}", "verbose=false", *map(str, cfg.extra)]
    learn = Job("learn", "phase 1: DrS learns (train map)", ["phase=learn", *map(str, cfg.learn), *common])
    ckpt = f"reward.checkpoint={out / 'learn' / 'reward.pt'}"
    drs = Job(
        "reuse-drs",
        "phase 2: DrS reward (test map)",
        ["phase=reuse", *map(str, cfg.reuse.drs), ckpt, *common],
        ["learn"],
    )
    base = [
        Job(f"reuse-{b}", f"phase 2: {LABELS.get(b, b)} (test map)", ["phase=reuse", *map(str, cfg.reuse[b]), *common])
        for b in cfg.baselines
    ]
    # phase 1 first, then a baseline beside it; DrS's reuse as soon as phase 1 is done
    return [learn, *base[:1], drs, *base[1:]]


def finished(run_dir: Path) -> bool:
    return (run_dir / "summary.json").is_file()


def remove_run(run_dir: Path) -> None:
    """Delete a run's folder (an unfinished run is started again, not resumed), unless a process still writes it: a run left
    behind by a quickstart that was killed outright, which the run's own lock names."""
    if not run_dir.exists():
        return
    try:
        lock_run_dir(run_dir, "choose another out=DIR")
    except RunDirBusyError as exc:
        raise QuickstartError(f"{exc} (a run of an earlier quickstart still going?)") from None
    try:
        shutil.rmtree(run_dir, ignore_errors=True)
    finally:
        unlock_run_dir(run_dir)


def prepare_out(out: Path, jobs: list[Job], overwrite: bool) -> list[str]:
    """Check ``out`` against an earlier quickstart there; returns the names of finished runs kept."""
    record = out / "quickstart.json"
    mine = {"plan": [asdict(j) for j in jobs]}
    if out.exists() and any(p.name not in ("logs", LOCK_NAME) for p in out.iterdir()):
        if not record.is_file():
            raise QuickstartError(f"{out} already holds files that are not a quickstart's; choose another out=DIR")
        if overwrite:
            for j in jobs:
                remove_run(out / j.name)
            for f in ("quickstart.png", "summary.json", "summary.md"):
                (out / f).unlink(missing_ok=True)
            shutil.rmtree(out / "logs", ignore_errors=True)
        else:
            try:
                theirs = json.loads(record.read_text())
            except (OSError, UnicodeDecodeError, ValueError) as exc:
                raise QuickstartError(
                    f"{record} is damaged ({exc.__class__.__name__}); start {out} afresh with "
                    "overwrite=true, or choose another out=DIR"
                ) from None
            if not isinstance(theirs, dict) or theirs.get("plan") != mine["plan"]:
                raise QuickstartError(
                    f"{out} holds a quickstart with other settings; continue it with the same "
                    f"overrides, choose another out=DIR, or start it afresh with overwrite=true"
                )
    out.mkdir(parents=True, exist_ok=True)
    (out / "logs").mkdir(exist_ok=True)
    record.write_text(json.dumps(mine, indent=1))
    return [j.name for j in jobs if finished(out / j.name)]


def last_row(run_dir: Path) -> dict | None:
    """The newest evaluation row of a run's ``train.csv`` (None before the first)."""
    try:
        with open(run_dir / "train.csv") as f:
            rows = list(csv.DictReader(f))
    except (FileNotFoundError, csv.Error):
        return None
    return rows[-1] if rows else None


class Progress:
    """One bar per running run (tqdm on a terminal), or one line per evaluation row."""

    def __init__(self, total: int, bars: bool | None):
        self.total = total
        # a terminal without a size (e.g. under `script`) gets lines: tqdm would draw nothing there
        self.bars = (
            (sys.stdout.isatty() and shutil.get_terminal_size((0, 0)).columns >= 60) if bars is None else bool(bars)
        )
        self.open: dict[str, object] = {}
        self.seen: dict[str, int] = {}
        self.t0 = time.perf_counter()

    def start(self, job: Job) -> None:
        if self.bars:
            from tqdm import tqdm

            self.open[job.name] = tqdm(
                total=self.total,
                desc=f"{job.title:<34}",
                unit="step",
                unit_scale=True,
                position=len(self.open),
                leave=True,
                file=sys.stdout,
                bar_format="{desc} {percentage:3.0f}%|{bar:16}| {n_fmt}/{total_fmt} [{elapsed}<{remaining}{postfix}]",
            )
        else:
            print(f"[{self._clock()}] {job.title}: started", flush=True)

    def update(self, job: Job, row: dict | None) -> None:
        if row is None:
            return
        frames = int(float(row["frames"]))
        stats = f"eval success {float(row['eval_success']):.2f}, train success {float(row['train_success']):.2f}"
        if "disc_accuracy" in row and row["disc_accuracy"] not in ("", "nan"):
            stats += f", disc acc {float(row['disc_accuracy']):.2f}"
        if self.bars and job.name in self.open:
            bar = self.open[job.name]
            bar.n = min(frames, self.total)
            bar.set_postfix_str(stats, refresh=True)
        elif frames > self.seen.get(job.name, -1):
            print(f"[{self._clock()}] {job.title}: {frames:>7d} steps, {stats}", flush=True)
        self.seen[job.name] = frames

    def end(self, job: Job, ok: bool) -> None:
        bar = self.open.get(job.name)
        if bar is not None:
            if ok:
                bar.n = self.total
            bar.refresh()
        elif not self.bars:
            print(f"[{self._clock()}] {job.title}: {'done' if ok else 'FAILED'}", flush=True)

    def close(self) -> None:
        for bar in self.open.values():
            bar.close()

    def _clock(self) -> str:
        s = int(time.perf_counter() - self.t0)
        return f"{s // 60:3d}m{s % 60:02d}s"


def run_jobs(jobs: list[Job], out: Path, n_parallel: int, progress: Progress, quiet: bool) -> int | None:
    """Run what is not finished, ``n_parallel`` at a time; returns None, or the signal that stopped it."""
    exe = [sys.executable, "-m", "drs_torchrl.apps.maze"]
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", DRS_CONF_DIR=_conf_dir())
    if quiet:
        env.update(RL_WARNINGS="0", RL_LOGGING_LEVEL="WARNING")
    else:
        env["DRS_LIBRARY_MESSAGES"] = "1"
    pending = [j for j in jobs if not finished(out / j.name)]
    active: dict[str, tuple[Job, subprocess.Popen]] = {}
    stop = {"sig": None}

    def on_signal(signum, frame):
        stop["sig"] = signum
        for _, proc in active.values():
            proc.send_signal(signal.SIGTERM)

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        while (pending or active) and stop["sig"] is None:
            for name, (job, proc) in list(active.items()):
                progress.update(job, last_row(out / name))
                if proc.poll() is not None:
                    del active[name]
                    ok = proc.returncode == 0 and finished(out / name)
                    progress.end(job, ok)
                    if not ok:
                        log = (out / "logs" / f"{name}.log").read_text(errors="replace").strip().splitlines()
                        tail = "\n    ".join(log[-8:])
                        raise QuickstartError(
                            f"run {name} failed (exit {proc.returncode}); the end of "
                            f"{out / 'logs' / (name + '.log')}:\n    {tail}"
                        )
            for job in list(pending):
                if len(active) >= n_parallel:
                    break
                if not all(finished(out / n) for n in job.needs):
                    continue
                remove_run(out / job.name)  # an unfinished run starts again: its result is then the uninterrupted one's
                log = open(out / "logs" / f"{job.name}.log", "a")
                # an unfinished run starts again (above), so a stopped one need not write its training state
                cmd = [*exe, *job.args, "save_state=false", f"hydra.run.dir={out / job.name}"]
                log.write(f"# {time.strftime('%Y-%m-%d %H:%M:%S')} {' '.join(cmd)}\n")
                log.flush()
                progress.start(job)
                active[job.name] = (job, subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env))
                pending.remove(job)
            time.sleep(1.0)
    finally:
        # stopped by a signal or by a failed run: the other runs stop too (nothing is left running)
        for _, proc in active.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
            proc.wait()
        for s, h in previous.items():
            signal.signal(s, h)
    return stop["sig"]


def _curve(run_dir: Path) -> tuple[list[float], list[float], list[float]]:
    with open(run_dir / "train.csv") as f:
        rows = list(csv.DictReader(f))
    frames = [float(r["frames"]) for r in rows]
    return frames, [float(r["eval_success"]) for r in rows], [float(r["train_success"]) for r in rows]


def first_solved(run_dir: Path) -> int | None:
    """Env steps of the first greedy evaluation at or above :data:`SUCCESS_BAR`."""
    frames, success, _ = _curve(run_dir)
    return next((int(f) for f, s in zip(frames, success) if s >= SUCCESS_BAR), None)


def spread_text(record: dict) -> list[str]:
    """The lines that set one seed against this command's committed record on other seeds (``record`` of
    conf/quickstart.yaml: per reward, greedy success on the test map by seed)."""
    if not record:
        return []
    parts = []
    for name, by_seed in record.items():
        if not by_seed:
            continue
        values = [float(v) for v in by_seed.values()]
        hits = sum(v >= SUCCESS_BAR for v in values)
        seeds = [int(k) for k in by_seed]
        span = (
            f"{seeds[0]}-{seeds[-1]}" if seeds == list(range(seeds[0], seeds[-1] + 1)) else ", ".join(map(str, seeds))
        )
        parts.append(
            f"{LABELS.get(name, name)} >= {SUCCESS_BAR} in {hits} of {len(values)} "
            f"(seeds {span}: {', '.join(f'{v:.2f}' for v in values)})"
        )
    return [
        "One seed says little. This command on other seeds (conf/quickstart.yaml `record`, each a committed",
        "summary.json):",
    ] + [f"  {p}" for p in parts]


def summarize(jobs: list[Job], out: Path, wall_s: float | None, record: dict | None = None) -> dict:
    """What the quickstart learned and how the reused reward compared: ``summary.json`` and ``summary.md``."""
    learn = json.loads((out / "learn" / "summary.json").read_text())
    row = last_row(out / "learn") or {}
    diag = learn.get("reward_diagnostics", {}).get("test", {})
    phase2 = {}
    for j in sorted(jobs[1:], key=lambda j: j.name != "reuse-drs"):  # DrS first, then the baselines
        s = json.loads((out / j.name / "summary.json").read_text())
        phase2[j.name.removeprefix("reuse-")] = {
            "success_last3": s["mean_eval_success_last3"],
            "final_success": s["final_eval_success"],
            "first_solved_at": first_solved(out / j.name),
            "wall_time_s": s["wall_time_s"],
        }
    summary = {
        "family": "three_room_maze",
        "seed": learn["seed"],
        "frames_per_run": learn["frames"],
        "wall_time_s": wall_s,
        "phase1": {
            "greedy_success_last3": learn["mean_eval_success_last3"],
            "train_success": float(row.get("train_success", "nan")),
            "disc_accuracy": float(row.get("disc_accuracy", "nan")),
            "disc_updates": learn.get("disc_updates"),
            "stage_buffer_counts": learn.get("stage_buffer_counts"),
            "test_map_best_action_is_shortest_path": diag.get("optimal_action_rate"),
            "test_map_always_up_reference": diag.get("always_up_rate"),
            "reward_checkpoint": str(out / "learn" / "reward.pt"),
        },
        "phase2": phase2,
        "figure": str(out / "quickstart.png"),
        "record": record or {},
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    (out / "summary.md").write_text(summary_text(summary, out) + "\n")
    return summary


def summary_text(s: dict, out: Path) -> str:
    p1, p2 = s["phase1"], s["phase2"]
    lines = []
    if s.get("wall_time_s") is not None:
        lines.append(
            f"drs-quickstart: done in {s['wall_time_s'] / 60:.1f} min, seed {s['seed']}, {s['frames_per_run']} env steps per run."
        )
    lines += [
        "",
        "Phase 1, train map (reward learning):",
        f"  the DQN reached the goal in {p1['train_success']:.0%} of its last training episodes (greedy: {p1['greedy_success_last3']:.2f});",
        f"  the discriminator (success vs not) took {p1['disc_updates']} steps and ends at accuracy {p1['disc_accuracy']:.2f};",
    ]
    if p1.get("test_map_best_action_is_shortest_path") is not None:
        lines.append(
            f"  on the test map its best action is a shortest-path move in {p1['test_map_best_action_is_shortest_path']:.0%} "
            f"of (cell, goal) pairs (always moving up: {p1['test_map_always_up_reference']:.0%})."
        )
    lines += [
        "",
        "Phase 2, test map (gates swapped), fresh DQN agents; greedy success, mean of the last 3 evaluations:",
    ]
    for name, r in p2.items():
        when = (
            f"first >= {SUCCESS_BAR} at {r['first_solved_at'] // 1000}k steps"
            if r["first_solved_at"] is not None
            else f"never >= {SUCCESS_BAR}"
        )
        lines.append(f"  {LABELS.get(name, name):<24} {r['success_last3']:.2f}   ({when})")
    drs = p2["drs"]["success_last3"]
    if "sparse" in p2:
        gap = drs - p2["sparse"]["success_last3"]
        lines += [
            "",
            f"The reused DrS reward {'beat' if gap >= 0.2 else 'did not clearly beat'} sparse, the paper's baseline "
            f"({drs:.2f} vs {p2['sparse']['success_last3']:.2f}).",
        ]
    if "semi_sparse" in p2:
        lines.append(
            f"Semi-sparse is DrS's own constant part without the learned term ({p2['semi_sparse']['success_last3']:.2f}); "
            f"on this maze the learned term has not been shown to add to it (results/maze/README.md)."
        )
    lines += spread_text(s.get("record", {}))
    lines += [
        "",
        f"Files: {out}/quickstart.png (figure), summary.json, summary.md; {out}/learn/reward.pt (the reward);",
        f"       each run's train.csv and TensorBoard (tb/) under {out}/<run>/, logs under {out}/logs/.",
        "Next:",
        f"  drs-quickstart seed={s['seed'] + 1}                      # another seed",
        f"  drs-maze phase=reuse reward.name=drs reward.checkpoint={out}/learn/reward.pt map=test_shift3 dqn.loss_function=l2 dqn.reward_scale=0.1",
        "  drs-learn env=turn_valve                   # DrS with SAC on a ManiSkill3 family (about an hour a phase on 2 cores)",
    ]
    return "\n".join(lines)


def plot(jobs: list[Job], out: Path) -> Path:
    """``quickstart.png``: phase-1 curves, phase-2 curves per reward, and the learned reward per cell."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.image as mpimg
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(13, 11))
    grid = fig.add_gridspec(2, 2, height_ratios=[1, 1.35])
    ax1, ax2, ax3 = fig.add_subplot(grid[0, 0]), fig.add_subplot(grid[0, 1]), fig.add_subplot(grid[1, :])
    frames, success, train = _curve(out / "learn")
    ax1.plot(frames, success, label="greedy evaluation")
    ax1.plot(frames, train, label="training episodes (epsilon-greedy)", alpha=0.7)
    ax1.set_title("phase 1: DQN + DrS reward learning (train map)")
    for j in sorted(jobs[1:], key=lambda j: j.name != "reuse-drs"):
        f, s, _ = _curve(out / j.name)
        name = j.name.removeprefix("reuse-")
        ax2.plot(f, s, label=LABELS.get(name, name), lw=2.5 if name == "drs" else 1.5)
    ax2.set_title("phase 2: fresh DQN on the test map (gates swapped)")
    for ax in (ax1, ax2):
        ax.set_xlabel("env steps")
        ax.set_ylabel("success rate")
        ax.set_ylim(-0.05, 1.05)
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left")
    reward_map = out / "learn" / "reward_map.png"
    if reward_map.is_file():
        ax3.imshow(mpimg.imread(reward_map))
    ax3.set_axis_off()
    fig.tight_layout()
    path = out / "quickstart.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


_EXISTED: dict[str, bool] = {}  # out folder -> whether it existed before Hydra made it (first resolution wins)


def _out_dir_resolver(out):
    """``hydra.run.dir`` (``${drs_quickstart_out:${out}}``): notes whether the folder existed before Hydra makes it,
    so that a refused quickstart removes only a folder Hydra made, never an empty one the user made beforehand."""
    _EXISTED.setdefault(str(out), Path(str(out)).exists())
    return out


OmegaConf.register_new_resolver("drs_quickstart_out", _out_dir_resolver, replace=True)


@console_script("drs-quickstart", quiet=False)  # its runs filter (or not: library_messages) themselves
@hydra.main(config_path=_conf_dir(), config_name="quickstart", version_base=None)
def main(cfg: DictConfig) -> None:
    """``drs-quickstart [seed=N] [baselines=[...]] [out=DIR] [overwrite=true]`` (see conf/quickstart.yaml)."""
    out = Path(HydraConfig.get().runtime.output_dir)
    if out.is_relative_to(Path.cwd()):  # shown and recorded as the user wrote it (runs/quickstart/seed0)
        out = out.relative_to(Path.cwd())
    try:
        check_added_settings(cfg, list(HydraConfig.get().overrides.task), "quickstart", "quickstart", QuickstartError)
        if not str(cfg.out).strip():
            raise QuickstartError(
                "out is empty (an unset shell variable?); name a folder, e.g. out=runs/quickstart/mine"
            )
        jobs = plan(cfg, out)
        lock_run_dir(out, "choose another out=DIR")  # one quickstart per folder (each run locks its own too)
        kept = prepare_out(out, jobs, bool(cfg.overwrite))
    except QuickstartError as exc:
        print(f"drs-quickstart: error: {exc}", file=sys.stderr)
        unlock_run_dir(out, remove_if_empty=True)  # (if this process took it)
        if _EXISTED.get(str(HydraConfig.get().run.dir)) is False:
            with contextlib.suppress(OSError):
                out.rmdir()  # the folder Hydra made for a refused quickstart, if it holds nothing
        sys.exit(2)
    todo = [j for j in jobs if j.name not in kept]
    print(f"drs-quickstart: DrS on the three-room maze, seed {cfg.seed}, into {out}", flush=True)
    print(
        "  phase 1 learns the reward on the train map; phase 2 reuses it on the test map"
        + (f" beside {', '.join(LABELS.get(b, b) for b in cfg.baselines)}" if cfg.baselines else "")
        + f"; {len(todo)} runs of {int(cfg.total_frames)} env steps, {int(cfg.jobs)} at a time"
        + (f" ({ESTIMATE} on an idle 2-core CPU at the defaults)" if len(todo) == len(jobs) else ""),
        flush=True,
    )
    for name in kept:
        print(f"  {name}: finished earlier, kept", flush=True)
    t0 = time.perf_counter()
    progress = Progress(int(cfg.total_frames), cfg.progress_bar)
    try:
        sig = run_jobs(todo, out, int(cfg.jobs), progress, quiet=not bool(cfg.library_messages))
    except QuickstartError as exc:
        progress.close()
        print(f"drs-quickstart: error: {exc}", file=sys.stderr)
        sys.exit(1)
    progress.close()
    if sig is not None:
        print(
            f"drs-quickstart: interrupted; finished runs are kept in {out}. Run the same command again to continue.",
            file=sys.stderr,
            flush=True,
        )
        sys.exit(128 + int(sig))
    plot(jobs, out)
    record = OmegaConf.to_container(cfg.get("record") or {})
    summary = summarize(jobs, out, round(time.perf_counter() - t0, 1) if todo else None, record)
    print("\n" + summary_text(summary, out), flush=True)


if __name__ == "__main__":
    main()
