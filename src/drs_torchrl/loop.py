"""The loop of Algorithm 1, over built pieces and for any RL algorithm.

Each round: collect a batch (line 5); file its finished episodes, into the stage buffers for DrS (lines 6-8);
hand the batch to the RL updater, which takes the updates the new env steps pay for and calls the reward
learner's step where it takes its own (lines 9-18); then log, evaluate and checkpoint on schedule. Phase 2 is the
same loop with no reward learner: the frozen reward sits in the env. What the loop receives is built elsewhere
(:class:`drs_torchrl.apps.build.Run` from the Hydra config, or by hand from TorchRL pieces).
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict
from torchrl import timeit
from tqdm.auto import tqdm

from drs_torchrl.data import TrajectoryAssembler
from drs_torchrl.runtime.signals import StopRequest
from drs_torchrl.updaters.base import NonFiniteError, Updater, check_finite


@dataclass
class Schedule:
    """When the loop logs, evaluates, checkpoints and stops (env steps)."""

    total_frames: int
    log_interval: int = 1000
    eval_interval: int = 20000
    checkpoint_interval: int = 20000
    stop_at_success: float | None = None  # end once the training success over a full episode window reaches it
    stop_at_eval_success: float | None = None  # end once stop_streak evaluations in a row reach it
    stop_streak: int = 1  # evaluations in a row that stop_at_eval_success needs


@dataclass
class Progress:
    """The loop's counters, saved with the training state."""

    frames: int = 0
    last_eval_frames: int = -1
    eval_streak: int = 0  # evaluations in a row, up to the last, whose success reached ``stop_at_eval_success``
    resumed_from: int | None = None
    # the run's earlier processes, one {"from", "to", "wall_s"} each (what each covered up to its last saved state)
    segments: list[dict] = field(default_factory=list)


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


@dataclass
class EpisodeWindow:
    """The last ``size`` finished training episodes, assembled across batch boundaries; ``reward_fn`` gives an
    episode's rewards under the reward being trained on (its return is logged)."""

    size: int
    num_stages: int
    reward_fn: Callable
    recent: deque = field(init=False)

    def __post_init__(self):
        self.recent = deque(maxlen=int(self.size))
        self.assembler = TrajectoryAssembler()

    def add(self, batch) -> list:
        episodes = self.assembler.add(batch)
        self.recent.extend(episode_summary(ep, self.reward_fn) for ep in episodes)
        return episodes

    @property
    def full(self) -> bool:
        return len(self.recent) == self.recent.maxlen

    def row(self) -> dict[str, float]:
        return aggregate_episodes(list(self.recent), self.num_stages) if self.recent else {}


class UpdateLog:
    """What happened since the last train-log row: update and reward-learner statistics, sampled rewards, env
    steps, updates, and the seconds spent waiting for data and updating (TorchRL's ``timeit`` timers
    ``drs/collect`` and ``drs/update``, read as differences so that other ``timeit`` users are left alone)."""

    TIMERS = ("collect", "update")

    def __init__(self):
        self.stats: list[TensorDict] = []
        self.learner_stats: list[TensorDict] = []
        self.rewards: list[torch.Tensor] = []
        self.frames = self.updates = 0
        self._start = self._totals()
        self.t0 = time.perf_counter()

    def update(self, stats: TensorDict, rewards: torch.Tensor | None = None) -> None:
        """One optimisation step's statistics, and the rewards it trained on (None: already logged)."""
        self.stats.append(stats)
        if rewards is not None:
            self.rewards.append(rewards.reshape(-1))

    def learner(self, stats: TensorDict | None) -> None:
        if stats is not None:
            self.learner_stats.append(stats)

    @classmethod
    def _totals(cls) -> dict[str, float]:
        totals = timeit.todict(percall=False)
        return {w: totals.get(f"drs/{w}", 0.0) for w in cls.TIMERS}

    def timed(self, what: str, fn, *args):
        with timeit(f"drs/{what}"):
            return fn(*args)

    def timing(self) -> dict[str, float]:
        dt = time.perf_counter() - self.t0
        now = self._totals()
        t_collect, t_update = (now[w] - self._start[w] for w in self.TIMERS)
        return {
            "env_steps_per_s": self.frames / max(dt, 1e-9),
            "updates_per_s": self.updates / max(t_update, 1e-9) if self.updates else 0.0,
            "collect_steps_per_s": self.frames / max(t_collect, 1e-9),
            # waiting for the collector (all of the simulation in-process; only the part not overlapped for a
            # background collector) vs updating
            "frac_time_waiting_for_data": t_collect / max(dt, 1e-9),
            "frac_time_updating": t_update / max(dt, 1e-9),
        }

    def means(self) -> dict[str, float]:
        """Mean update statistics, sampled-reward statistics, mean reward-learner statistics (``disc_*``)."""
        row = {}
        if self.stats:
            st = torch.stack(self.stats)
            row.update({k: float(st[k].float().mean()) for k in st.keys()})
        if self.rewards:
            r = torch.cat(self.rewards)
            check_finite("rewards", r)
            row.update(
                reward_mean=float(r.mean()),
                reward_std=float(r.std()),
                reward_min=float(r.min()),
                reward_max=float(r.max()),
            )
        if self.learner_stats:
            st = torch.stack(self.learner_stats)
            row.update({f"disc_{k}": float(st[k].float().mean()) for k in st.keys()})
        return row


class Every:
    """Due every ``interval`` env steps, counted from 0 (a resumed run keeps the same schedule)."""

    def __init__(self, interval: int, frames: int):
        self.interval = int(interval)
        self.next = (frames // self.interval + 1) * self.interval

    def due(self, frames: int) -> bool:
        if frames < self.next:
            return False
        self.next = (frames // self.interval + 1) * self.interval
        return True


def _rss_mib(pid: int | str = "self") -> float:
    try:
        with open(f"/proc/{pid}/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return float("nan")


def resident_memory() -> dict[str, float]:
    """Resident memory in MiB of this process (``rss_mib``) and of its worker processes (``rss_workers_mib``: a
    background collector's simulator), for train.csv: a long run's memory must stay flat once its buffers are full.
    NaN where ``/proc`` is absent."""
    workers = [_rss_mib(c.pid) for c in multiprocessing.active_children()]
    return {"rss_mib": _rss_mib(), "rss_workers_mib": float(sum(workers)) if workers else 0.0}


def run_algorithm1(
    collector: Iterable,
    updater: Updater,
    *,
    learner,
    episodes: EpisodeWindow,
    logger,
    evaluate: Callable[[], dict],
    save: Callable[[], dict],
    schedule: Schedule,
    progress: Progress,
    sync_policy: Callable[[], None] | None = None,
    name: str = "drs",
    progress_bar: bool = True,
    where: str = "",
) -> dict[str, Any]:
    """Algorithm 1 from ``progress.frames`` to ``schedule.total_frames`` env steps, or to a stop signal.

    ``learner``: the reward learner (phase 1) or None; ``evaluate()``: an evaluation row; ``save()``: the
    checkpoints and training state (returns the checkpoint paths); ``sync_policy()``: after updates, send the new
    weights to a background collector; ``where``: the checkpoint directory named by a non-finite error.
    Returns the summary (``frames``, ``updates``, ``interrupted``, ``last_eval``, ...).
    """
    summary: dict[str, Any] = {}
    log, t0, frames0 = UpdateLog(), time.perf_counter(), progress.frames
    log_at, eval_at, ckpt_at = (
        Every(i, progress.frames) for i in (schedule.log_interval, schedule.eval_interval, schedule.checkpoint_interval)
    )
    learner_step = learner.update if learner is not None else None
    bar = tqdm(
        total=schedule.total_frames, initial=progress.frames, desc=name, unit="step", disable=not progress_bar,
        dynamic_ncols=True,
    )  # fmt: skip

    def train_row() -> dict[str, float]:
        row = {"frames": progress.frames, "updates": updater.updates, **log.timing(), **resident_memory()}
        row.update(**episodes.row(), **log.means())
        return {**row, **(learner.log_row() if learner is not None else {})}

    def evaluate_and_log() -> bool:
        """Evaluate and log; True when ``stop_at_eval_success`` is now reached."""
        ev = evaluate()
        progress.last_eval_frames = progress.frames
        if not ev:
            return False
        logger.log("eval", progress.frames, ev)
        summary["last_eval"] = ev
        return _eval_reached(schedule, ev, progress, summary, name)

    interrupted = forced = False
    with StopRequest() as stop:  # stays until the end: the final evaluation and saves stop cleanly too
        it = iter(collector)
        try:
            while (batch := log.timed("collect", next, it, None)) is not None:
                check_finite("observations", batch.get(("next", "observation")))
                n = batch.numel()
                progress.frames += n
                updater.extend(batch)
                finished = episodes.add(batch)
                if learner is not None:
                    learner.observe(batch, finished)  # DrS files them by stage; VICE-RAQ labels every state
                updater.after_collect(n)
                n_updates = log.timed("update", updater.update, n, progress.frames, learner_step, log)
                if n_updates and sync_policy is not None:
                    sync_policy()  # a background worker collects the next batch with the updated policy
                log.frames, log.updates = log.frames + n, log.updates + n_updates
                bar.update(n)
                if log_at.due(progress.frames):
                    row = train_row()
                    logger.log("train", progress.frames, row)
                    bar.set_postfix(success=f"{row.get('success_rate', 0):.2f}", sps=f"{row['env_steps_per_s']:.0f}")
                    log = UpdateLog()
                    if _reached(schedule.stop_at_success, episodes, row, progress, summary, name):
                        break
                if eval_at.due(progress.frames) and evaluate_and_log():
                    break
                if ckpt_at.due(progress.frames):
                    save()
                    logger.flush()
                if stop.signum is not None:  # SIGINT/SIGTERM: stop here, between two rounds
                    interrupted, summary["signal"] = True, int(stop.signum)
                    tqdm.write(f"signal {stop.signum} at {progress.frames} env steps: saving the training state")
                    break
        except KeyboardInterrupt:  # a second Ctrl-C forces the stop wherever the loop was
            interrupted = forced = True
            summary["signal"] = int(signal.SIGINT)
            tqdm.write(
                f"forced stop at {progress.frames} env steps: the last periodic training state is kept "
                "(the buffers may be mid-write, so nothing is saved now)"
            )
        except NonFiniteError as exc:
            raise NonFiniteError(
                f"{exc} at env step {progress.frames} ({updater.name} update {updater.updates}); the run stopped "
                f"without saving, so the last good checkpoint{' in ' + where if where else ''} is intact"
            ) from None
        finally:
            bar.close()
        elapsed = time.perf_counter() - t0
        if log.frames:
            logger.log("train", progress.frames, train_row())
        if not interrupted and progress.last_eval_frames != progress.frames:
            evaluate_and_log()
        if not forced:
            summary["checkpoints"] = save()
        else:
            summary["frames_at_last_state"] = int(progress.frames)  # informational; resume uses the saved state
    summary.update(
        frames=progress.frames,
        updates=updater.updates,
        disc_updates=learner.updates if learner is not None else 0,
        wall_time_s=elapsed,
        env_steps_per_s=(progress.frames - frames0) / max(elapsed, 1e-9),
        interrupted=interrupted,
    )
    if learner is not None:
        summary.update(learner.summary())
    return summary


def _eval_reached(schedule: Schedule, ev: dict, progress: Progress, summary: dict, name: str) -> bool:
    """``stop_at_eval_success``: ``stop_streak`` evaluations in a row reached it (a comparison's "env steps to
    success" is then known, and the rest of the budget would only confirm it); the run ends as finished."""
    target = schedule.stop_at_eval_success
    if target is None:
        return False
    reached = float(ev.get("success_rate", 0.0)) >= float(target)
    progress.eval_streak = progress.eval_streak + 1 if reached else 0
    if progress.eval_streak < schedule.stop_streak:
        return False
    summary["stopped_at_eval_success"] = {
        "success_rate": float(ev["success_rate"]),
        "threshold": float(target),
        "streak": int(schedule.stop_streak),
        "frames": int(progress.frames),
    }
    tqdm.write(
        f"{name}: evaluation success {float(ev['success_rate']):.2f} >= eval.stop_at_success={float(target):g} "
        f"in {schedule.stop_streak} evaluation(s) in a row at {progress.frames} env steps: stopping"
    )
    return True


def _reached(target, episodes: EpisodeWindow, row: dict, progress: Progress, summary: dict, name: str) -> bool:
    """``stop_at_success``: the training success rate over a full episode window reached it (phase 1 "until the
    agent succeeds"); the run then ends as finished, with its final evaluation and saves."""
    if target is None or not episodes.full or row.get("success_rate", 0.0) < float(target):
        return False
    summary["stopped_at_success"] = {
        "success_rate": float(row["success_rate"]),
        "threshold": float(target),
        "frames": int(progress.frames),
        "episodes": len(episodes.recent),
    }
    tqdm.write(
        f"{name}: training success {row['success_rate']:.2f} over the last {len(episodes.recent)} episodes "
        f">= stop_at_success={float(target):g} at {progress.frames} env steps: stopping"
    )
    return True
