"""algo.precision: bf16 autocast of the learner with fp32 master weights, detection of native support."""

from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf
from tensordict import TensorDict
from torchrl.modules import MLP

from drs_torchrl.precision import OutputFloat32, PrecisionError, native_bf16, resolve_precision
from drs_torchrl.apps.cli import conf_dir
from drs_torchrl.apps.build import Run
from budgets import small


def _cpuinfo_flags() -> set[str]:
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("flags"):
            return set(line.split(":", 1)[1].split())
    return set()


@pytest.mark.skipif(not Path("/proc/cpuinfo").is_file(), reason="reads the CPU flags from /proc/cpuinfo (Linux)")
def test_auto_is_bf16_exactly_where_the_cpu_has_bf16_instructions():
    native = bool(_cpuinfo_flags() & {"avx512_bf16", "amx_bf16"})
    assert native_bf16("cpu") == native
    assert resolve_precision("auto", "cpu") == ("bf16" if native else "fp32")
    assert resolve_precision("bf16", "cpu") == "bf16"  # asked for explicitly: allowed (emulated where not native)
    assert resolve_precision("fp32", "cpu") == "fp32"


def test_unknown_or_unsupported_precisions_are_refused():
    with pytest.raises(PrecisionError, match="auto|fp32|bf16|fp16"):
        resolve_precision("fp8", "cpu")
    with pytest.raises(PrecisionError, match="needs a CUDA device.*bf16"):
        resolve_precision("fp16", "cpu")


def test_output_cast_adds_no_parameters():
    plain = MLP(in_features=5, out_features=2, num_cells=[8, 8])
    cast = MLP(in_features=5, out_features=2, num_cells=[8, 8])
    cast.append(OutputFloat32())
    assert list(cast.state_dict()) == list(plain.state_dict())  # old policy checkpoints still load
    cast.load_state_dict(plain.state_dict())
    x = torch.randn(3, 5)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        assert plain(x).dtype == torch.bfloat16
        assert cast(x).dtype == torch.float32


TINY = small(eval_every=None, eval_episodes=0, checkpoint_every=1_000_000)


def _trainer(tmp_path, precision):
    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        cfg = compose("learn", overrides=[*TINY, f"algo.precision={precision}"])
    return Run(cfg, "learn", tmp_path)


def _file_a_success(tr) -> None:
    """A successful episode of zeros in the top stage buffer, as a demonstration goes (a random policy grasps
    nothing in 640 steps): every discriminator then has positives, and negatives once the agent's first episode
    ends, so each SAC update takes its discriminator step."""
    spec, n = tr.env.observation_spec, tr.learner.reward.num_stages
    ep = TensorDict(
        {
            "observation": torch.zeros(10, *spec["observation"].shape[-1:]),
            "stage_indicators": torch.ones(10, *spec["stage_indicators"].shape[-1:]),
            "stage": torch.full((10, 1), n),
        },
        batch_size=[10],
    )
    tr.learner.stage_buffers.add_trajectory(TensorDict({"next": ep}, batch_size=[10]), demo=True)


@pytest.mark.slow
@pytest.mark.sim
def test_bf16_learner_multiplies_in_bf16_and_keeps_fp32_weights_state_and_losses(tmp_path):
    tr = _trainer(tmp_path, "bf16")
    assert tr.precision == "bf16"
    _file_a_success(tr)
    before = {k: v.clone() for k, v in tr.updater.loss.qvalue_network_params.items(True, True)}
    seen = {}
    hidden = next(m for m in tr.updater.loss.qvalue_network.modules() if isinstance(m, torch.nn.Linear))

    def record(module, inputs, output):
        seen.setdefault("hidden", set()).add(output.dtype)

    hook = hidden.register_forward_hook(record)
    summary = tr.run()
    hook.remove()
    # 64-step batches from 256 to 640 env steps at UTD 0.5, a discriminator step for each SAC update
    a = tr.cfg.algo
    updates = len(range(a.learning_starts, tr.cfg.total_frames + 1, a.frames_per_batch)) * a.frames_per_batch * a.utd
    assert summary["precision"] == "bf16" and summary["updates"] == updates == 224
    assert summary["disc_updates"] == updates * tr.cfg.algo.reward_updates_per_update == 224
    assert seen["hidden"] == {torch.bfloat16}  # every critic matrix product ran in bf16 (none escaped autocast in vmap)
    params = dict(tr.updater.loss.named_parameters())
    assert params and all(p.dtype == torch.float32 for p in params.values())
    after = dict(tr.updater.loss.qvalue_network_params.items(True, True))
    assert any(not torch.equal(before[k], after[k]) for k in before)  # it trained
    for opt in (tr.updater.optimizers["actor"], tr.updater.optimizers["critic"], tr.learner.optim):
        assert opt.state  # it stepped
        for st in opt.state.values():
            assert st["exp_avg"].dtype == torch.float32 and st["exp_avg_sq"].dtype == torch.float32
    for d in tr.learned.discriminators.parameters():
        assert d.dtype == torch.float32


@pytest.mark.slow
@pytest.mark.sim
def test_bf16_sac_loss_matches_fp32_on_the_same_batch(tmp_path):
    """Same networks, same replay batch, same sampling noise: the bf16 losses are the fp32 ones
    up to bf16 rounding of the matrix products (learning itself is compared in results/precision/)."""
    tr = _trainer(tmp_path, "fp32")
    tr.run()
    sample = tr.updater.replay.sample()
    losses = {}
    for name, ctx in (
        ("fp32", torch.autocast("cpu", enabled=False)),
        ("bf16", torch.autocast("cpu", dtype=torch.bfloat16)),
    ):
        torch.manual_seed(0)
        with ctx:
            out = tr.updater.loss(sample.clone())
        losses[name] = {k: float(out[k]) for k in ("loss_actor", "loss_qvalue", "loss_alpha")}
        assert all(out[k].dtype == torch.float32 for k in ("loss_actor", "loss_qvalue"))
    for k, v in losses["fp32"].items():
        assert losses["bf16"][k] == pytest.approx(v, rel=0.05, abs=0.02), (k, losses)


@pytest.mark.sim
def test_bad_precision_override_is_a_config_error(tmp_path):
    with pytest.raises(PrecisionError, match="needs a CUDA device"):
        _trainer(tmp_path, "fp16")
    assert not (tmp_path / "config.yaml").exists()  # nothing written for a run that cannot start


@pytest.mark.sim
def test_default_learner_is_bf16_exactly_where_native_with_the_critics_one_after_the_other(tmp_path):
    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        cfg = compose("learn", overrides=TINY)
    assert cfg.algo.precision == "auto"
    tr = Run(cfg, "learn", tmp_path)
    try:
        assert tr.precision == ("bf16" if native_bf16("cpu") else "fp32")
        assert tr.updater.loss.deactivate_vmap  # autocast reaches every critic; faster than vmap here in fp32 too
        saved = OmegaConf.load(tmp_path / "config.yaml")
        assert saved.algo.precision == tr.precision  # resolved: a resume elsewhere keeps the run's precision
        assert cfg.algo.precision == "auto"  # recorded in config.yaml, not written into the composed config
    finally:
        tr.close()
