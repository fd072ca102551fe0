"""Bad input mid-run: non-finite values stop the run and keep the last good checkpoint."""

import pytest
import torch
from hydra import compose, initialize_config_dir

from drs_torchrl.apps.cli import conf_dir
from drs_torchrl.updaters.base import NonFiniteError
from drs_torchrl.apps.build import Run
from drs_torchrl.runtime.checkpoint import TrainingStateError
from drs_torchrl.transforms import DrSReward
from budgets import tiny

pytestmark = pytest.mark.sim

TINY = tiny(frames=1024, eval_episodes=0, checkpoint_every=256)


def cfg(*extra):
    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        return compose("learn", overrides=[*TINY, *extra])


class PoisonAfterFirstCheckpoint(Run):
    """Corrupts the critic right after the first good checkpoint (a diverging run)."""

    def save_training_state(self):
        out = super().save_training_state()
        with torch.no_grad():
            for p in self.updater.loss.qvalue_network_params.values(True, True):
                p.fill_(float("nan"))
        return out


@pytest.mark.slow
def test_nan_stops_the_run_and_keeps_the_last_good_checkpoint(tmp_path):
    tr = PoisonAfterFirstCheckpoint(cfg(), "learn", tmp_path)
    with pytest.raises(NonFiniteError, match=r"non-finite SAC loss at env step \d+"):
        tr.run()
    saved = int((tmp_path / "checkpoints" / "state" / "COMPLETE").read_text())
    assert saved == 256
    payload = torch.load(tmp_path / "checkpoints" / "state" / "trainer.pt", weights_only=True)
    assert all(torch.isfinite(v).all() for v in payload["loss"].values() if v.is_floating_point())
    DrSReward.from_checkpoint(tmp_path / "checkpoints" / "reward.pt")  # finite, loadable
    # and the run resumes from it
    tr2 = Run(cfg(), "learn", tmp_path, resume=True)
    assert tr2.frames == 256
    tr2.close()


@pytest.mark.slow
def test_damaged_training_state_is_reported(tmp_path):
    Run(cfg("total_frames=256"), "learn", tmp_path).run()
    for f in (tmp_path / "checkpoints" / "state" / "replay").rglob("observation.memmap"):
        f.write_bytes(f.read_bytes()[:10])
    with pytest.raises(TrainingStateError, match="damaged.*truncated"):
        Run(cfg(), "learn", tmp_path, resume=True)
