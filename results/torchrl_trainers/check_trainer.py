"""Scratch check: does DrS fit as hooks on torchrl.trainers (torchrl 0.14.1)?

CPU-light: Pendulum-v1, tiny nets, a few hundred frames, one thread.
Run from the repository root:  OMP_NUM_THREADS=1 .venv/bin/python results/torchrl_trainers/check_trainer.py
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import tempfile
import time
import warnings
from collections import Counter
from pathlib import Path

import torch
from tensordict import TensorDict
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn

torch.set_num_threads(1)
warnings.filterwarnings("ignore")

from torchrl.checkpoint import Checkpoint
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.envs import Compose, GymEnv, RewardSum, StepCounter, TransformedEnv
from torchrl.envs.transforms import Transform
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import SACLoss, SoftUpdate
from torchrl.record.loggers import CSVLogger
from torchrl.trainers import MixedPrecisionOptimizationStepper, Trainer
from torchrl.trainers.algorithms import SACTrainer

from drs_torchrl.data import TrajectoryAssembler  # read-only use of the project's episode assembler

OUT = Path(tempfile.mkdtemp(prefix="trainer_eval-"))
FPB, MAX_STEPS, INIT_RANDOM = 50, 75, 100  # episodes of 75 steps span batches of 50


def make_env(seed=0):
    env = TransformedEnv(GymEnv("Pendulum-v1"), Compose(StepCounter(max_steps=MAX_STEPS), RewardSum()))
    env.set_seed(seed)
    return env


def make_sac(env, seed=0):
    torch.manual_seed(seed)
    n_act = env.action_spec.shape[-1]
    actor_net = nn.Sequential(MLP(out_features=2 * n_act, num_cells=[32]), NormalParamExtractor())
    actor = ProbabilisticActor(
        TensorDictModule(actor_net, in_keys=["observation"], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"],
        spec=env.action_spec,
        distribution_class=TanhNormal,
        return_log_prob=False,
    )
    q = ValueOperator(MLP(out_features=1, num_cells=[32]), in_keys=["observation", "action"])
    with torch.no_grad():
        td = env.fake_tensordict()
        actor(td)
        q(td)
    loss = SACLoss(actor, q, num_qvalue_nets=2, deactivate_vmap=True)
    loss.make_value_estimator(
        gamma=0.99
    )  # eager, or a fresh loss cannot load a trained one (lazy _value_estimator.gamma)
    return actor, loss, SoftUpdate(loss, tau=0.005), torch.optim.Adam(loss.parameters(), lr=3e-4)


class CountingReward(Transform):
    """Stand-in for the learned reward: rewrites ("next","reward") at replay sampling and counts its calls."""

    def __init__(self):
        super().__init__(in_keys=[], out_keys=[])
        self.calls = 0
        self.version = 0.0  # bumped by the "reward learner" step, so samples show which version rewarded them

    def forward(self, td):
        self.calls += 1
        td.set(("next", "reward"), torch.full_like(td.get(("next", "reward")), self.version))
        return td

    _call = forward

    def _inv_call(self, td):
        return td


class DrSHooks:
    """What DrS would add: file finished episodes (batch_process), one learner step per optim step (post_optim),
    a stop rule and an evaluation (post_steps_log). Checkpointable through state_dict/load_state_dict."""

    def __init__(self, reward: CountingReward, trainer=None):
        self.reward = reward
        self.assembler = TrajectoryAssembler()
        self.trainer = trainer
        self.log = Counter()
        self.batch_shapes, self.episode_lengths, self.optim_at = [], [], []
        self.sampled_reward_versions = []

    # batch_process: every collected batch, before the frame count and before anything else sees it
    def on_batch(self, batch):
        self.log["batch_process"] += 1
        self.batch_shapes.append(tuple(batch.shape))
        for ep in self.assembler.add(batch):
            self.episode_lengths.append(int(ep.shape[0]))
        return batch

    # post_optim: once per optimisation step (here: the reward learner's step)
    def on_optim(self):
        self.log["post_optim"] += 1
        self.reward.version += 1.0
        self.optim_at.append(self.trainer.collected_frames)

    # process_optim_batch: sees the sampled sub-batch (registered after SACTrainer's sampler, so it gets the sample)
    def on_sub_batch(self, sub_batch):
        self.log["process_optim_batch"] += 1
        self.sampled_reward_versions.append(float(sub_batch.get(("next", "reward")).float().mean()))
        return sub_batch

    # post_steps_log: once per collected batch, after the optimisation steps
    def on_after_steps(self, batch):
        self.log["post_steps_log"] += 1
        return {"episodes_done": float(len(self.episode_lengths))}

    def state_dict(self):
        return {"version": self.reward.version, "n_episodes": len(self.episode_lengths), "log": dict(self.log)}

    def load_state_dict(self, sd):
        self.reward.version = float(sd["version"])
        self.restored = sd


def build_sac_trainer(tag, total_frames, ckpt_path=None, logger=None, seed=0, optim_steps=4):
    env = make_env(seed)
    actor, loss, target, optim = make_sac(env, seed)
    reward = CountingReward()
    rb = ReplayBuffer(storage=LazyTensorStorage(10_000), batch_size=32, transform=reward)
    collector = Collector(env, actor, frames_per_batch=FPB, total_frames=total_frames, init_random_frames=INIT_RANDOM)
    trainer = SACTrainer(
        collector=collector,
        total_frames=total_frames,
        frame_skip=1,
        optim_steps_per_batch=optim_steps,
        loss_module=loss,
        optimizer=optim,
        replay_buffer=rb,
        target_net_updater=target,
        logger=logger,
        progress_bar=False,
        seed=seed,
        log_interval=0,
        save_trainer_interval=10**9,
        checkpoint=Checkpoint() if ckpt_path else None,
        save_trainer_file=ckpt_path,
        episode_reward_key="episode_reward",  # the default "reward_sum" is not what RewardSum writes
    )
    hooks = DrSHooks(reward, trainer)
    trainer.register_op("batch_process", hooks.on_batch)
    trainer.register_op("post_optim", hooks.on_optim)
    trainer.register_op("process_optim_batch", hooks.on_sub_batch)
    trainer.register_op("post_steps_log", hooks.on_after_steps)
    trainer.register_module("drs", hooks)
    return trainer, hooks, rb, reward, loss, optim


def part_a():
    """Hooks fire as expected? What happens before init_random_frames?"""
    t0 = time.perf_counter()
    trainer, hooks, rb, reward, loss, optim = build_sac_trainer("a", 400)
    trainer.train()
    n_batches = 400 // FPB
    learning_batches = sum(1 for f in range(FPB, 401, FPB) if f >= INIT_RANDOM)
    return {
        "seconds": round(time.perf_counter() - t0, 2),
        "hook_calls": dict(hooks.log),
        "expected": {
            "batch_process": n_batches,
            "post_steps_log": n_batches,
            "post_optim": learning_batches * 4,
            "process_optim_batch": learning_batches * 4,
        },
        "batch_shapes": sorted(set(hooks.batch_shapes)),
        "episode_lengths_assembled": hooks.episode_lengths,
        "collected_frames": trainer.collected_frames,
        "optim_count": trainer._optim_count,
        "replay_buffer_len": len(rb),
        "frames_lost_before_init_random_frames": trainer.collected_frames - len(rb),
        "reward_transform_calls": reward.calls,
        "first_sampled_reward_versions": hooks.sampled_reward_versions[:6],
    }


def read_csv_steps(logdir):
    rows = {}
    for f in Path(logdir).rglob("*.csv"):
        with open(f) as fh:
            rows[f.stem] = [int(float(r[0])) for r in csv.reader(fh) if r]
    return rows


def part_b():
    """torchrl checkpointing of the trainer: what is saved, what comes back, logger rows after a resume."""
    ck = OUT / "ckpt_at_200"
    logdir = OUT / "logs"
    shutil.rmtree(OUT, ignore_errors=True)
    OUT.mkdir(parents=True)
    logger_a = CSVLogger("run", log_dir=str(logdir))
    trainer, hooks, rb, reward, loss, optim = build_sac_trainer(
        "b1", 400, ckpt_path=str(OUT / "final"), logger=logger_a
    )

    saved = {}

    def save_mid():  # a scheduled save at 200 frames (save_trainer_interval is frame based; forced here for a fixed step)
        if trainer.collected_frames == 200 and not saved:
            trainer.checkpoint.save(ck)
            saved.update(
                frames=trainer.collected_frames,
                optim=trainer._optim_count,
                rb=len(rb),
                rng=torch.get_rng_state().clone(),
                collector_frames=trainer.collector._frames,
                episodes=len(hooks.episode_lengths),
                partial=len(hooks.assembler._partial),
                params=TensorDict.from_module(loss).clone(),
                adam_step=float(next(iter(optim.state.values()))["step"]),
            )

    trainer.register_op("post_steps", save_mid)
    trainer.train()
    manifest = Checkpoint.manifest(ck)
    components = sorted(manifest["components"])
    csv_before_resume = read_csv_steps(logdir)

    # --- a new process would build everything again and load ---
    logger_b = CSVLogger("run", log_dir=str(logdir))
    trainer2, hooks2, rb2, reward2, loss2, optim2 = build_sac_trainer(
        "b2", 400, ckpt_path=str(OUT / "final2"), logger=logger_b, seed=0
    )
    torch.manual_seed(12345)  # perturb the global RNG: is it restored?
    trainer2.load_from_file(ck)
    p2 = TensorDict.from_module(loss2)
    restored = {
        "trainer.collected_frames": (trainer2.collected_frames, saved["frames"]),
        "trainer._optim_count": (trainer2._optim_count, saved["optim"]),
        "replay_buffer_len": (len(rb2), saved["rb"]),
        "collector._frames": (trainer2.collector._frames, saved["collector_frames"]),
        "loss params equal": bool((p2 == saved["params"]).all()),
        "adam step": (float(next(iter(optim2.state.values()))["step"]) if optim2.state else None, saved["adam_step"]),
        "global torch RNG equal": bool(torch.equal(torch.get_rng_state(), saved["rng"])),
        "custom module (drs) restored": getattr(hooks2, "restored", None),
        "reward version": (reward2.version, None),
        "assembler partial episodes": (len(hooks2.assembler._partial), saved["partial"]),
        "logger in-memory scalar rows (r_training)": len(logger_b.experiment.scalars.get("r_training", [])),
    }
    trainer2.train()  # continue 200 -> 400
    csv_after = read_csv_steps(logdir)
    dup = {k: [s for s, c in Counter(v).items() if c > 1] for k, v in csv_after.items()}
    # legacy (no Checkpoint) state_dict keys
    legacy_keys = sorted(build_sac_trainer("b3", 100)[0].state_dict().keys())
    return {
        "checkpoint_components": components,
        "restored (got, saved)": restored,
        "csv rows r_training before resume": csv_before_resume.get("r_training"),
        "csv rows r_training after resume": csv_after.get("r_training"),
        "duplicated steps per csv file (after resume)": {k: v for k, v in dup.items() if v},
        "legacy Trainer.state_dict keys (no Checkpoint)": legacy_keys,
    }


class UTDHook:
    """Fractional updates-per-env-step on the base Trainer: optim_steps_per_batch=None and a process_optim_batch
    hook that raises StopIteration once the owed updates are spent (the only way to end the open-ended loop)."""

    def __init__(self, trainer, rb, utd, learning_starts):
        self.trainer, self.rb, self.utd, self.learning_starts = trainer, rb, utd, learning_starts
        self.owed, self.last_frames, self.done_updates, self.learner_steps = 0.0, 0, 0, 0
        self.left = 0

    def extend(self, batch):  # batch_process: every batch goes to the replay buffer, also before learning starts
        self.last_frames = self.trainer.collected_frames  # batch_process runs before the trainer counts the batch
        self.rb.extend(batch.reshape(-1).exclude("collector", "loc", "scale"))
        return batch

    def pre_optim(self):  # pre_optim_steps: how many updates this batch owes
        new = self.trainer.collected_frames - self.last_frames
        if self.trainer.collected_frames < self.learning_starts:
            self.left = 0
            return
        self.owed += new * self.utd
        self.left = int(self.owed)
        self.owed -= self.left

    def sample(self, _batch):  # process_optim_batch: reward-learner step, then the SAC batch (reward recomputed)
        if self.left == 0:
            raise StopIteration
        self.left -= 1
        self.learner_steps += 1
        self.done_updates += 1
        return self.rb.sample()


def part_c():
    """Base Trainer built from objects: fractional UTD via hooks, bf16 autocast stepper, SIGTERM -> request_stop."""
    env = make_env(1)
    actor, loss, target, optim = make_sac(env, 1)
    reward = CountingReward()
    rb = ReplayBuffer(storage=LazyTensorStorage(10_000), batch_size=32, transform=reward)
    collector = Collector(env, actor, frames_per_batch=FPB, total_frames=600, init_random_frames=INIT_RANDOM)
    stepper = MixedPrecisionOptimizationStepper(
        optim, mixed_precision=True, autocast_dtype=torch.bfloat16, clip_norm=None, device_type="cpu"
    )
    trainer = Trainer(
        collector=collector,
        total_frames=600,
        frame_skip=1,
        optim_steps_per_batch=None,
        loss_module=loss,
        optimizer=optim,
        optimization_stepper=stepper,
        progress_bar=False,
        save_trainer_interval=10**9,
        checkpoint=Checkpoint(),
        save_trainer_file=str(OUT / "sig_ckpt"),
        log_interval=0,
    )
    utd = UTDHook(trainer, rb, utd=1 / 3, learning_starts=INIT_RANDOM)
    trainer.register_op("batch_process", utd.extend)
    trainer.register_op("pre_optim_steps", utd.pre_optim)
    trainer.register_op("process_optim_batch", utd.sample)
    trainer.register_op("post_optim", lambda: target.step())

    dtypes = []
    lin = next(m for m in loss.actor_network.modules() if isinstance(m, nn.Linear))
    lin.register_forward_hook(lambda m, i, o: dtypes.append(str(o.dtype)) if torch.is_grad_enabled() else None)

    # SIGTERM at the 5th batch: a handler asks the trainer to stop; it saves at the batch boundary and exits
    batches = Counter()

    def count(batch):
        batches["n"] += 1
        if batches["n"] == 5:
            os.kill(os.getpid(), signal.SIGTERM)
        return batch

    trainer.register_op("batch_process", count)
    prev = signal.signal(signal.SIGTERM, lambda s, f: trainer.request_stop(f"signal {s}"))
    try:
        trainer.train()
    finally:
        signal.signal(signal.SIGTERM, prev)
    return {
        "collected_frames_at_stop": trainer.collected_frames,
        "stop_reason": trainer._stop_reason,
        "saved_on_stop": Checkpoint.is_checkpoint(OUT / "sig_ckpt"),
        "real_updates": utd.done_updates,
        "expected_updates_at_utd_1/3": int((trainer.collected_frames - (INIT_RANDOM - FPB)) / 3),
        "trainer._optim_count": trainer._optim_count,
        "stepper.optimizer_step_count": stepper.optimizer_step_count,
        "actor Linear output dtypes seen with grad (learner forward)": sorted(set(dtypes)),
        "replay_buffer_len": len(rb),
    }


def part_d():
    """OfflineToOnlineReplayBuffer: demonstrations as a fixed share of each batch, rewarded by the current transform."""
    from torchrl.data import OfflineToOnlineReplayBuffer

    env = make_env(2)
    demo = env.rollout(60).exclude("collector")
    demo.set("is_demo", torch.ones(demo.shape[0], 1, dtype=torch.bool))
    offline = ReplayBuffer(storage=LazyTensorStorage(100))
    offline.extend(demo)
    reward = CountingReward()
    reward.version = 7.0
    o2o = OfflineToOnlineReplayBuffer(
        offline, online_capacity=1000, offline_fraction=0.25, batch_size=32, transform=reward
    )
    online = env.rollout(60).exclude("collector")
    online.set("is_demo", torch.zeros(online.shape[0], 1, dtype=torch.bool))
    o2o.extend(online)
    s = o2o.sample()
    return {
        "batch": s.shape[0],
        "demo_rows": int(s["is_demo"].sum()),
        "all rewards rewritten by transform": bool((s["next", "reward"] == 7.0).all()),
        "transform calls (one per sample)": reward.calls,
        "OfflineToOnlineReplayBuffer checkpointable itself": Trainer._is_checkpointable(o2o),
    }


if __name__ == "__main__":
    res = {}
    for name, fn in (
        ("A_hooks", part_a),
        ("B_checkpoint_resume", part_b),
        ("C_base_trainer_utd_bf16_signal", part_c),
        ("D_offline_to_online", part_d),
    ):
        t = time.perf_counter()
        try:
            res[name] = fn()
        except Exception as exc:  # report, keep going
            import traceback

            res[name] = {"error": repr(exc), "tb": traceback.format_exc()[-2000:]}
        res[name]["_seconds"] = round(time.perf_counter() - t, 2)
    print(json.dumps(res, indent=1, default=str))
    (Path(__file__).parent / "results.json").write_text(json.dumps(res, indent=1, default=str))
