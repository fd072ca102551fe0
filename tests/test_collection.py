"""The background collector (a TorchRL AsyncCollector process beside the learner, issue 4):
the worker acts with the learner's current actor, the UTD stays exact, and runs finish and save."""

import json

import pytest
import torch
from hydra import compose, initialize_config_dir

from drs_torchrl.apps.cli import conf_dir
from drs_torchrl.apps.build import Run
from budgets import small


BACKGROUND = "algo.collector._target_=torchrl.collectors.AsyncCollector"
TINY = small(
    frames=None,
    learning_starts=None,
    log_every=None,
    eval_every=None,
    eval_episodes=0,
    checkpoint_every=1_000_000,
    background=True,
)


def config(*overrides):
    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        return compose("learn", overrides=[BACKGROUND, *TINY, *overrides])


@pytest.mark.sim
@pytest.mark.slow
def test_background_worker_acts_with_the_updated_actor(tmp_path):
    tr = Run(config("total_frames=100000", "algo.learning_starts=0"), "learn", tmp_path)
    assert tr.collects_in_background
    collector = tr.make_collector(64 * 6)
    try:
        it = iter(collector)
        first = next(it)
        assert (first["action"] - 1).abs().max() > 0.5  # the fresh actor explores
        # make the learner's actor output a saturated +1 action everywhere, then sync the worker
        last = [m for m in tr.actor.modules() if isinstance(m, torch.nn.Linear)][-1]  # output layer: (loc, scale)
        with torch.no_grad():
            last.weight.zero_()
            last.bias.zero_()
            last.bias[: last.bias.numel() // 2] = 20.0  # loc: tanh(20) = 1
            last.bias[last.bias.numel() // 2 :] = -20.0  # scale: at its lower bound
        collector.update_policy_weights_()
        next(it)  # may have been collected before the sync (one batch of policy lag)
        after = next(it)
        assert torch.allclose(after["action"], torch.ones_like(after["action"]), atol=1e-3)
    finally:
        collector.shutdown()
        tr.close()


@pytest.mark.sim
@pytest.mark.slow
def test_background_run_keeps_utd_exact_and_saves(tmp_path):
    tr = Run(
        config("total_frames=768", "algo.learning_starts=256", "algo.frames_per_batch=64", "logger.interval=256"),
        "learn",
        tmp_path,
    )
    summary = tr.run()
    assert summary["frames"] == 768
    # the config's UTD (sac_cpu: 0.5) for every 64-step batch that ends at or after learning_starts (256, 320, ..., 768)
    assert summary["updates"] == len(range(256, 769, 64)) * int(64 * float(tr.cfg.algo.utd))
    assert (tmp_path / "checkpoints" / "reward.pt").is_file()
    assert (tmp_path / "checkpoints" / "state" / "COMPLETE").is_file()
    assert sum(json.loads((tmp_path / "summary.json").read_text())["stage_buffer_episodes"]) >= 10


@pytest.mark.parametrize("target", ["torchrl.collectors.AsyncCollector", "torchrl.collectors.MultiAsyncCollector"])
def test_a_gpu_learner_gets_the_in_process_collector_and_the_cpu_keeps_the_background_one(target):
    """drs-reuse's default algo (sac_cpu) collects in a background process, which cannot feed a CUDA learner:
    with device=cuda the in-process Collector replaces it (noted on the console, saved in the config).
    Found on the H200 device check (results/gpu/): `drs-reuse device=cuda` refused to start."""
    from drs_torchrl.apps.validation import collector_for_device

    cfg = config(f"algo.collector._target_={target}", "+algo.collector.num_workers=2")
    node, note = collector_for_device(cfg.algo.collector, torch.device("cpu"))
    assert note is None and node._target_ == target and node.num_workers == 2

    node, note = collector_for_device(cfg.algo.collector, torch.device("cuda"))  # a device object only: no GPU needed
    assert note is not None and target in note and "in-process" in note
    assert node._target_ == "torchrl.collectors.Collector" and "num_workers" not in node
    assert node.frames_per_batch == cfg.algo.frames_per_batch  # resolved: the node stands alone (make_collector)
    assert cfg.algo.collector._target_ == target and cfg.algo.collector.num_workers == 2  # the config is not changed
    assert collector_for_device(node, torch.device("cuda")) == (node, None)  # already in-process: nothing to change


def test_config_yaml_records_what_the_run_resolved_and_the_composed_config_stays_as_composed(tmp_path):
    """save_config: the values a run resolves (a collector for the device, auto settings, a reused reward's) replace
    the composed ones in config.yaml, whole nodes included; algo.updater stays linked to the algo settings."""
    from omegaconf import OmegaConf

    from drs_torchrl.apps.build import save_config

    cfg = config("algo.collector._target_=torchrl.collectors.MultiAsyncCollector", "+algo.collector.num_workers=2")
    resolved = {
        "algo.collector": {"_target_": "torchrl.collectors.Collector", "_partial_": True, "frames_per_batch": 64},
        "algo.precision": "bf16",
        "demos.sac_share": 0.25,
        "env.task_observation": True,
    }
    save_config(cfg, tmp_path / "config.yaml", resolved)
    saved = OmegaConf.load(tmp_path / "config.yaml")
    assert OmegaConf.to_container(saved.algo.collector) == resolved["algo.collector"]  # replaced, not merged
    assert saved.algo.precision == "bf16" and saved.demos.sac_share == 0.25 and saved.env.task_observation is True
    assert OmegaConf.to_container(saved.algo.updater)["gamma"] == "${algo.gamma}"  # a link, as before
    assert cfg.algo.collector.num_workers == 2 and cfg.algo.precision == "auto"
