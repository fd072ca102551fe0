"""Run budgets of the command-line tests: a few hundred env steps with the smallest networks, so that a real
ManiSkill run (simulation, SAC, the discriminators) ends in seconds. A test file states only what it needs to
differ; ``None`` leaves that setting at the config's value."""

# the HalfCheetah family at a budget where an episode ends inside a tiny run (Appendix H's family)
HALF_CHEETAH = ["env=half_cheetah", "env.max_episode_steps=100", "env.variant_overrides.success_return=1.0"]


def tiny(
    *,
    frames: int | None = 320,
    learning_starts: int | None = 128,
    batch: int = 32,
    hidden: int = 16,
    disc_batch: int | None = 16,
    log_every: int | None = 128,
    eval_every: int | None = 100_000,
    eval_episodes: int = 1,
    checkpoint_every: int = 100_000,
    progress_bar: bool | None = False,
    background: bool = False,
) -> list[str]:
    """Overrides of ``drs-learn`` / ``drs-reuse`` for a tiny run (``disc_batch=None`` for a reward without a learner).

    ``background=False``: TorchRL's in-process ``Collector`` (what the studies run) instead of the config's
    background ``AsyncCollector``, whose worker process imports torch and builds its own env (several CPU-seconds a
    run). The runs that test the default path keep it (``background=True``): the default run of test_cli, the
    interrupts and resumes, the console's filtering in the worker, and test_collection."""
    settings = {
        "total_frames": frames,
        "algo.learning_starts": learning_starts,
        "algo.batch_size": batch,
        "algo.hidden": f"[{hidden},{hidden}]",
        "reward.disc.batch_size": disc_batch,
        "logger.interval": log_every,
        "eval.interval": eval_every,
        "eval.episodes": eval_episodes,
        "checkpoint_interval": checkpoint_every,
        "logger.progress_bar": None if progress_bar is None else str(progress_bar).lower(),
        "logger.tensorboard": "false",
        "algo.collector._target_": None if background else "torchrl.collectors.Collector",
    }
    return [f"{key}={value}" for key, value in settings.items() if value is not None]


def small(**changes) -> list[str]:
    """:func:`tiny` at twice its budget and network width (640 env steps, 256 before learning, batch 64)."""
    base = dict(frames=640, learning_starts=256, batch=64, hidden=32, disc_batch=32, log_every=256)
    return tiny(**{**base, **changes})
