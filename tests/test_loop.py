"""The loop of Algorithm 1 by itself (:func:`drs_torchrl.loop.run_algorithm1`): driven by a list of synthetic batches
and stub updater, learner, logger, evaluation and save, with no simulator. Pinned: the order of the calls in a round,
the updates a fractional UTD owes (with the SAC updater's own ``update``), no update before ``learning_starts``, the
log / evaluation / checkpoint schedule, the stop at success (finished, not interrupted), SIGTERM and SIGINT (stop at
the next batch boundary and save; a second SIGINT forces the stop without saving), a non-finite observation, and the
summary's fields."""

from __future__ import annotations

import functools
import os
import signal

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Bounded, Composite, LazyTensorStorage, ReplayBuffer, Unbounded
from torchrl.objectives import SACLoss, SoftUpdate

from drs_torchrl.loop import EpisodeWindow, Every, Progress, Schedule, run_algorithm1
from drs_torchrl.updaters.base import NonFiniteError, UpdateBudget, Updater
from drs_torchrl.updaters.sac import make_sac_updater

OBS, ACT, STAGES = 6, 2, 2
BATCH = 64  # env steps per collected batch (sac_cpu's frames_per_batch)
EPISODE = 16  # every batch ends four episodes


def batch(i: int, *, n: int = BATCH, success: bool = False, reward: float = -1.5) -> TensorDict:
    """Collected batch ``i`` of one env: ``n`` steps, an episode ending every :data:`EPISODE` steps (at the top
    stage and successful when ``success``), reward ``reward`` at every step."""
    t = torch.arange(i * n, (i + 1) * n)
    done = ((t + 1) % EPISODE == 0).unsqueeze(-1)
    stage = torch.where(done & success, STAGES, 0)
    g = torch.Generator().manual_seed(i)
    return TensorDict(
        {
            "observation": torch.randn(n, OBS, generator=g),
            "stage_indicators": torch.zeros(n, STAGES),
            "action": torch.rand(n, ACT, generator=g) * 2 - 1,
            "next": {
                "observation": torch.randn(n, OBS, generator=g),
                "stage_indicators": torch.zeros(n, STAGES),
                "stage": stage,
                "success": done & success,
                "reward": torch.full((n, 1), reward),
                "done": done,
                "terminated": done & success,
            },
        },
        batch_size=[n],
    )


class Calls(list):
    """Every call the loop makes on its collaborators, in order: ``(who, *args)``."""

    def of(self, who: str) -> list[tuple]:
        return [c for c in self if c[0] == who]


class StubUpdater(Updater):
    """Takes ``per_batch`` updates per batch once ``learning_starts`` env steps are in; each update calls the
    learner's step first, as SAC does, and logs a loss of 2.0 and rewards of 0.5."""

    name = "stub"

    def __init__(self, calls: Calls, per_batch: int = 3, learning_starts: int = 0, hook=None):
        super().__init__()
        self.calls, self.per_batch, self.learning_starts, self.hook = calls, per_batch, learning_starts, hook

    def extend(self, batch):
        self.calls.append(("extend", batch.numel()))

    def after_collect(self, frames):
        self.calls.append(("after_collect", frames))

    def update(self, frames, total_frames, learner_step, log):
        self.calls.append(("update", frames, total_frames, learner_step))
        if self.hook is not None:
            self.hook(total_frames)
        if total_frames < self.learning_starts:
            return 0
        for _ in range(self.per_batch):
            if learner_step is not None:
                log.learner(learner_step())
            self.updates += 1
            log.update(TensorDict({"loss": torch.tensor(2.0)}, []), torch.full((4,), 0.5))
        return self.per_batch


class StubLearner:
    def __init__(self, calls: Calls):
        self.calls, self.updates = calls, 0

    def observe(self, batch, finished):
        self.calls.append(("observe", batch.numel(), len(finished)))

    def update(self):
        self.updates += 1
        return TensorDict({"loss_0": torch.tensor(0.25)}, [])

    def log_row(self):
        return {"stage_buffer_0": 7.0}

    def summary(self):
        return {"stage_buffer_episodes": [3, 1]}


class StubLogger:
    def __init__(self, calls: Calls):
        self.calls = calls

    def log(self, stream, step, row):
        self.calls.append(("log", stream, step, dict(row)))

    def flush(self):
        self.calls.append(("flush",))


def run(
    batches,
    *,
    updater=None,
    learner=True,
    total=None,
    log_interval=10**9,
    eval_interval=10**9,
    checkpoint_interval=10**9,
    stop_at_success=None,
    stop_at_eval_success=None,
    stop_streak=1,
    eval_success=(0.5,),
    window=4,
    progress=None,
    sync=False,
    calls=None,
):
    """``run_algorithm1`` over ``batches``; returns (summary, calls, updater, learner)."""
    calls = calls if calls is not None else Calls()
    batches = list(batches)
    updater = updater if updater is not None else StubUpdater(calls)
    stub_learner = StubLearner(calls) if learner else None

    evals = iter(eval_success)

    def evaluate():  # the evaluations' success rates in turn, the last one repeated
        calls.append(("evaluate",))
        evaluate.last = next(evals, evaluate.last)
        return {"success_rate": evaluate.last}

    evaluate.last = eval_success[-1]

    def save():
        calls.append(("save",))
        return {"policy": "policy.pt"}

    summary = run_algorithm1(
        iter(batches),
        updater,
        learner=stub_learner,
        episodes=EpisodeWindow(window, STAGES, lambda ep: ep.get(("next", "reward"))),
        logger=StubLogger(calls),
        evaluate=evaluate,
        save=save,
        schedule=Schedule(
            total_frames=total or BATCH * len(batches),
            log_interval=log_interval,
            eval_interval=eval_interval,
            checkpoint_interval=checkpoint_interval,
            stop_at_success=stop_at_success,
            stop_at_eval_success=stop_at_eval_success,
            stop_streak=stop_streak,
        ),
        progress=progress if progress is not None else Progress(),
        sync_policy=(lambda: calls.append(("sync_policy",))) if sync else None,
        progress_bar=False,
    )
    return summary, calls, updater, stub_learner


def names(calls) -> list[str]:
    return [c[0] if c[0] != "log" else f"log {c[1]}" for c in calls]


# ---------------------------------------------------------------------------------------------- one round
def test_a_round_files_the_batch_then_updates_then_logs_evaluates_and_saves_in_that_order():
    summary, calls, updater, learner = run(
        [batch(0), batch(1)], log_interval=BATCH, eval_interval=2 * BATCH, checkpoint_interval=2 * BATCH, sync=True
    )
    per_round = ["extend", "observe", "after_collect", "update", "sync_policy", "log train"]
    # the end of the run: no unlogged frames, the last evaluation was at the last frame, the final save
    assert names(calls) == [*per_round, *per_round, "evaluate", "log eval", "save", "flush", "save"]
    # what each call was handed: the batch's env steps, the frames so far, the learner's update as the step
    assert calls.of("extend") == [("extend", 64), ("extend", 64)]
    assert calls.of("observe") == [("observe", 64, 4), ("observe", 64, 4)]  # four episodes end in each batch
    assert calls.of("after_collect") == [("after_collect", 64), ("after_collect", 64)]
    assert [c[1:3] for c in calls.of("update")] == [(64, 64), (64, 128)]
    assert all(c[3] == learner.update for c in calls.of("update"))
    assert updater.updates == 6 and learner.updates == 6
    assert summary["updates"] == 6 and summary["disc_updates"] == 6 and summary["frames"] == 128


def test_the_train_row_holds_the_updates_the_episodes_and_the_learner_since_the_last_row():
    _, calls, _, _ = run([batch(0), batch(1, success=True), batch(2)], log_interval=2 * BATCH)
    rows = [c for c in calls if c[:2] == ("log", "train")]
    assert [r[2] for r in rows] == [128, 192]  # the second at the end: its frames were not logged yet
    first, last = rows[0][3], rows[1][3]
    assert first["frames"] == 128 and first["updates"] == 6 and last["updates"] == 9
    assert first["loss"] == 2.0 and first["reward_mean"] == 0.5 and first["reward_std"] == 0.0
    assert first["disc_loss_0"] == 0.25 and first["stage_buffer_0"] == 7.0
    # the window of the last 4 episodes: at 128 env steps the 4 successes of batch 1; at 192 the 4 failures of batch 2
    assert first["episodes"] == 4.0 and first["success_rate"] == 1.0 and first["reach_stage_2"] == 1.0
    assert last["success_rate"] == 0.0 and last["episode_length"] == 16.0
    assert first["episode_return"] == pytest.approx(16 * -1.5)  # the episode's rewards under the reward_fn
    assert {"env_steps_per_s", "frac_time_updating", "rss_mib"} <= set(first)


def test_the_summary_names_frames_updates_learner_steps_checkpoints_and_the_last_evaluation():
    summary, _, _, _ = run([batch(i) for i in range(3)])
    assert summary["frames"] == 192 and summary["updates"] == 9 and summary["disc_updates"] == 9
    assert summary["interrupted"] is False and "signal" not in summary and "stopped_at_success" not in summary
    assert summary["checkpoints"] == {"policy": "policy.pt"} and summary["last_eval"] == {"success_rate": 0.5}
    assert summary["stage_buffer_episodes"] == [3, 1]  # the learner's own summary
    assert summary["wall_time_s"] > 0 and summary["env_steps_per_s"] == pytest.approx(192 / summary["wall_time_s"])


def test_phase_2_has_no_learner_step_and_no_learner_in_the_summary():
    summary, calls, _, _ = run([batch(0), batch(1)], learner=False)
    assert not calls.of("observe") and all(c[3] is None for c in calls.of("update"))
    assert summary["disc_updates"] == 0 and "stage_buffer_episodes" not in summary


def test_no_sync_of_a_background_collector_after_a_round_without_updates():
    calls = Calls()
    updater = StubUpdater(calls, learning_starts=3 * BATCH)
    run([batch(i) for i in range(4)], updater=updater, sync=True, calls=calls)
    assert names(calls).count("sync_policy") == 2  # rounds 3 and 4 (at 192 and 256 env steps) updated
    assert updater.updates == 6


def test_an_empty_collector_still_evaluates_and_saves():
    """A resumed run with nothing left to collect: no round, the final evaluation and save."""
    summary, calls, _, _ = run([], total=128, progress=Progress(frames=128))
    assert names(calls) == ["evaluate", "log eval", "save"]
    assert summary["frames"] == 128 and summary["updates"] == 0


# ---------------------------------------------------------------------------------------------- the schedule
@pytest.mark.parametrize(
    "interval,due",
    [
        (64, [64, 128, 192, 256, 320, 384, 448, 512, 576, 640]),
        (100, [128, 256, 320, 448, 512, 640]),  # the first batch end at or past each multiple of 100
        (256, [256, 512]),
        (1000, []),
    ],
)
def test_evaluations_and_checkpoints_come_at_the_first_batch_end_past_each_interval(interval, due):
    summary, calls, _, _ = run([batch(i) for i in range(10)], eval_interval=interval, checkpoint_interval=interval)
    at, frames = {"evaluate": [], "save": []}, 0
    for c in calls:
        if c[0] == "extend":
            frames += c[1]
        elif c[0] in at:
            at[c[0]].append(frames)
    final_eval = [] if due[-1:] == [640] else [640]  # the run ends evaluated at its last frame, once
    assert at["evaluate"] == due + final_eval
    assert at["save"] == due + [640]  # and saved at its end, after any periodic save
    assert names(calls).count("flush") == len(due)  # a periodic save flushes the logger


def test_a_resumed_run_keeps_the_schedule_counted_from_zero():
    progress = Progress(frames=320, last_eval_frames=256)
    _, calls, _, _ = run([batch(i) for i in range(5, 10)], progress=progress, eval_interval=256, total=640)
    evals = [c[2] for c in calls if c[:2] == ("log", "eval")]
    assert evals == [512, 640] and progress.frames == 640 and progress.last_eval_frames == 640


@pytest.mark.parametrize("interval,due", [(64, 10), (100, 6), (300, 2), (10**9, 0)])
def test_every_is_due_once_per_interval_crossed(interval, due):
    every = Every(interval, 0)
    assert sum(every.due(f) for f in range(64, 641, 64)) == due


# ---------------------------------------------------------------------------------------------- update budget
def sac(utd: float, learning_starts: int, batch_size: int = 32):
    """The real SAC updater over tiny networks, its optimisation step replaced by a counter (the loop and
    ``SACUpdater.update`` decide how many steps; :mod:`tests.test_updaters` pins the step itself)."""

    class Env:
        observation_spec = Composite(observation=Unbounded((OBS,)), stage_indicators=Unbounded((STAGES,)))
        action_spec = Bounded(-1.0, 1.0, (ACT,))

    u = make_sac_updater(
        Env(),
        ReplayBuffer(storage=LazyTensorStorage(100_000), batch_size=batch_size),
        loss=functools.partial(SACLoss, num_qvalue_nets=2, deactivate_vmap=True),
        optim=functools.partial(torch.optim.Adam, lr=3e-4),
        target_update=functools.partial(SoftUpdate, tau=0.005),
        hidden=[8],
        policy_in_keys=["observation", "stage_indicators"],
        gamma=0.8,
        utd=utd,
        learning_starts=learning_starts,
    )
    steps = []

    def step():
        u.updates += 1
        steps.append(len(u.replay))
        return TensorDict({"loss_actor": torch.tensor(0.0)}, []), torch.zeros(4)

    u.step = step
    return u, steps


def per_round_updates(calls: Calls, n_rounds: int) -> list[int]:
    """The updates of each round, from the train rows (logged after every round: ``log_interval=BATCH``)."""
    totals = [c[3]["updates"] for c in calls if c[:2] == ("log", "train")]
    assert len(totals) == n_rounds
    return [b - a for a, b in zip([0, *totals], totals)]


def test_utd_one_half_takes_32_updates_per_64_step_batch_and_one_learner_step_each():
    u, steps = sac(0.5, 0)
    calls = Calls()
    summary, _, _, learner = run([batch(i) for i in range(20)], updater=u, log_interval=BATCH, calls=calls)
    assert per_round_updates(calls, 20) == [32] * 20
    assert summary["updates"] == 640 and u.budget.owed == 0.0
    assert learner.updates == 640  # the learner's step is offered once per SAC update
    assert steps[:32] == [64] * 32 and steps[-1] == 1280  # each round's updates see that round's batch stored


def test_utd_one_third_carries_the_remainder_over_300_batches():
    """sac_cpu_utd033: 64/3 updates owed per batch, never an update lost or late: 22 at every third batch, the
    total of 300 batches exactly 6400."""
    u, _ = sac(1 / 3, 0)
    calls = Calls()
    summary, _, _, _ = run([batch(i % 7) for i in range(300)], updater=u, log_interval=BATCH, calls=calls)
    counts = per_round_updates(calls, 300)
    assert set(counts) == {21, 22} and counts[:6] == [21, 21, 22, 21, 21, 22]
    assert summary["updates"] == 6400 and u.budget.owed == pytest.approx(0.0, abs=1e-9)


def test_utd_one_third_takes_exactly_the_updates_owed_at_each_boundary():
    budget = UpdateBudget(1 / 3)
    assert [budget.take(64) for _ in range(6)] == [21, 21, 22, 21, 21, 22]  # 64/3, 128/3, 192/3 = 64, ...


def test_no_update_before_learning_starts_nor_before_the_replay_holds_a_batch():
    u, steps = sac(0.5, learning_starts=256)
    calls = Calls()
    summary, _, _, learner = run([batch(i) for i in range(8)], updater=u, log_interval=BATCH, calls=calls)
    # learning starts with the round that brings the 256th env step: nothing owed for the env steps before
    assert per_round_updates(calls, 8) == [0, 0, 0, 32, 32, 32, 32, 32]
    assert summary["updates"] == 160 and learner.updates == 160 and min(steps) == 256
    # a replay batch larger than what is stored: no update until it holds one (then only the new steps pay)
    u, _ = sac(0.5, learning_starts=0, batch_size=100)
    calls = Calls()
    run([batch(i) for i in range(3)], updater=u, log_interval=BATCH, calls=calls)
    assert per_round_updates(calls, 3) == [0, 32, 32]


# ---------------------------------------------------------------------------------------------- stopping
def test_stop_at_success_ends_the_run_finished_once_a_full_window_reaches_it():
    batches = [batch(0), batch(1), batch(2, success=True), batch(3, success=True), batch(4, success=True)]
    summary, calls, _, _ = run(batches, log_interval=BATCH, stop_at_success=0.75, window=8)
    # at 192 env steps the window of 8 episodes holds 4 successes (0.5); at 256, 8 of 8
    assert summary["stopped_at_success"] == {"success_rate": 1.0, "threshold": 0.75, "frames": 256, "episodes": 8}
    assert summary["frames"] == 256 and summary["interrupted"] is False and "signal" not in summary
    assert names(calls)[-2:] == ["log eval", "save"]  # finished: the final evaluation and save
    assert len(calls.of("extend")) == 4


def test_stop_at_success_waits_for_a_full_window():
    batches = [batch(0, success=True), batch(1, success=True), batch(2)]
    summary, _, _, _ = run(batches, log_interval=BATCH, stop_at_success=0.5, window=12)
    # 8 successes of 8 episodes at 128 env steps: the window of 12 is not full yet; at 192 it holds 8 of 12
    assert summary["stopped_at_success"]["frames"] == 192 and summary["stopped_at_success"]["success_rate"] == 2 / 3
    summary, _, _, _ = run(batches, log_interval=BATCH, stop_at_success=None, window=4)
    assert "stopped_at_success" not in summary and summary["frames"] == 192


def test_eval_stop_at_success_ends_the_run_after_a_streak_of_evaluations_and_a_lower_one_resets_it():
    batches = [batch(i) for i in range(8)]
    # evaluations at 64, 128, ...: 0.8, 0.6 (the streak resets), 0.9, 0.8 -> the second in a row at 256
    summary, calls, _, _ = run(
        batches, eval_interval=BATCH, stop_at_eval_success=0.8, stop_streak=2, eval_success=(0.8, 0.6, 0.9, 0.8, 0.1)
    )
    assert summary["stopped_at_eval_success"] == {"success_rate": 0.8, "threshold": 0.8, "streak": 2, "frames": 256}
    assert summary["frames"] == 256 and summary["interrupted"] is False
    assert len(calls.of("extend")) == 4 and len(calls.of("evaluate")) == 4  # no second evaluation at the end
    assert names(calls)[-3:] == ["log eval", "log train", "save"]  # finished: its last rows, then the final save
    summary, calls, _, _ = run(batches, eval_interval=BATCH, stop_at_eval_success=None, eval_success=(1.0,))
    assert "stopped_at_eval_success" not in summary and summary["frames"] == 8 * BATCH


def test_the_evaluation_streak_is_part_of_the_progress_a_resume_continues():
    progress = Progress(frames=0, eval_streak=1)  # the saved state's streak: one evaluation reached it already
    summary, _, _, _ = run(
        [batch(i) for i in range(4)], eval_interval=BATCH, stop_at_eval_success=0.5, stop_streak=2,
        eval_success=(0.5,), progress=progress,
    )  # fmt: skip
    assert summary["stopped_at_eval_success"]["frames"] == BATCH and progress.eval_streak == 2


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_stops_the_run_at_the_next_batch_boundary_and_saves(signum):
    before = signal.getsignal(signum)
    calls = Calls()

    def send(total_frames):
        if total_frames == 192:  # in the third round's update
            os.kill(os.getpid(), signum)

    updater = StubUpdater(calls, hook=send)
    summary, _, _, _ = run([batch(i) for i in range(6)], updater=updater, log_interval=BATCH * 100, calls=calls)
    assert summary["interrupted"] is True and summary["signal"] == int(signum)
    assert summary["frames"] == 192 and updater.updates == 9  # the round finished its updates
    # stopped: its unlogged row, no final evaluation, the training state saved
    assert names(calls)[-6:] == ["extend", "observe", "after_collect", "update", "log train", "save"]
    assert summary["checkpoints"] == {"policy": "policy.pt"} and "last_eval" not in summary
    assert signal.getsignal(signum) is before  # the loop's handler is gone


def test_a_second_ctrl_c_forces_the_stop_without_saving():
    calls = Calls()

    def twice(total_frames):
        if total_frames == 128:
            os.kill(os.getpid(), signal.SIGINT)
            os.kill(os.getpid(), signal.SIGINT)  # the second raises KeyboardInterrupt inside the loop

    summary, _, _, _ = run([batch(i) for i in range(4)], updater=StubUpdater(calls, hook=twice), calls=calls)
    assert summary["interrupted"] is True and summary["signal"] == int(signal.SIGINT)
    assert summary["frames_at_last_state"] == 128 and "checkpoints" not in summary
    assert not calls.of("save") and not calls.of("evaluate")


def test_a_non_finite_observation_stops_without_saving_and_names_where():
    bad = batch(2)
    bad["next", "observation"][5, 0] = float("nan")
    calls = Calls()
    with pytest.raises(NonFiniteError, match=r"non-finite observations at env step 128 \(stub update 6\)"):
        run([batch(0), batch(1), bad, batch(3)], calls=calls)
    assert len(calls.of("extend")) == 2 and not calls.of("save")
