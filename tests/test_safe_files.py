"""Files from elsewhere run no code: every loader refuses a crafted pickle in one line (exit 2 from the console
scripts) and nothing in it runs; a run's config.yaml may instantiate only the library's targets; drs-convert
rewrites a file of an earlier version (numpy arrays in it) without running anything either."""

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf
from tensordict import NonTensorData, TensorDict

from drs_torchrl.runtime.safe_files import UnsafeFileError, allowed_target, check_targets, convert_file, torch_load

REPO = Path(__file__).resolve().parents[1]
RECORD = REPO / "results" / "recipe" / "stack_cube" / "run_files" / "learn_s0"  # a committed phase-1 run


class Payload:
    """Unpickling it makes a directory: the proof that a loader ran the file's code."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (os.mkdir, (self.marker,))


def crafted(path: Path, marker: Path, **fields) -> Path:
    """A torch file that looks like one of ours (``fields``) and carries a payload."""
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({**fields, "extra": Payload(marker)}, path)
    return path


def test_the_crafted_file_runs_its_code_under_a_full_unpickling(tmp_path):
    """The fixture is real: without weights_only the payload runs (so the tests below can fail)."""
    marker = tmp_path / "ran"
    f = crafted(tmp_path / "x.pt", marker)
    torch.load(f, weights_only=False)
    assert marker.is_dir()


def one_line_refusal(exc: BaseException, path: Path) -> None:
    msg = str(exc)
    assert "\n" not in msg and str(path) in msg and "refused" in msg and "drs-convert" in msg


@pytest.mark.parametrize("what", ["policy", "reward", "state", "sampler"])
def test_every_loader_refuses_a_crafted_pickle_and_runs_nothing(tmp_path, what):
    from drs_torchrl.runtime.checkpoint import Checkpointer
    from drs_torchrl.data.persistence import dump_buffer, load_buffer
    from drs_torchrl.models import read_policy_checkpoint
    from drs_torchrl.transforms.reward import read_reward_checkpoint
    from torchrl.data import LazyTensorStorage, ReplayBuffer, SamplerWithoutReplacement

    marker = tmp_path / "ran"
    if what == "policy":
        f = crafted(tmp_path / "run" / "checkpoints" / "policy.pt", marker, format="drs-torchrl/policy")
        load = lambda: read_policy_checkpoint(tmp_path / "run")  # noqa: E731
    elif what == "reward":
        f = crafted(tmp_path / "reward.pt", marker, format="drs-torchrl/reward", config={}, state_dict={})
        load = lambda: read_reward_checkpoint(f)  # noqa: E731
    elif what == "state":
        state = tmp_path / "run" / "checkpoints" / "state"
        f = crafted(state / "trainer.pt", marker, format="drs-torchrl/training-state", version=1, phase="learn")
        (state / "COMPLETE").write_text("256")
        load = lambda: Checkpointer(tmp_path / "run").read_state("learn")  # noqa: E731
    else:
        rb = ReplayBuffer(storage=LazyTensorStorage(8), sampler=SamplerWithoutReplacement(), batch_size=2)
        rb.extend(TensorDict({"x": torch.arange(4.0)}, [4]))
        rb.sample()  # a sampler with a state: dump_buffer writes sampler.pt
        dump_buffer(rb, tmp_path / "buf")
        f = crafted(tmp_path / "buf" / "sampler.pt", marker)
        assert f.is_file()
        fresh = ReplayBuffer(storage=LazyTensorStorage(8), sampler=SamplerWithoutReplacement(), batch_size=2)
        load = lambda: load_buffer(fresh, tmp_path / "buf")  # noqa: E731
    with pytest.raises(UnsafeFileError) as info:
        load()
    one_line_refusal(info.value, f)
    assert "posix.mkdir" in str(info.value) or "os.mkdir" in str(info.value)
    assert not marker.exists()


def test_a_saved_tensordict_with_a_pickle_sidecar_is_refused(tmp_path):
    from drs_torchrl.data.persistence import load_memmap_checked

    marker = tmp_path / "ran"
    TensorDict({"a": torch.zeros(2), "b": NonTensorData(Payload(marker))}, []).memmap(tmp_path / "td")
    with pytest.raises(UnsafeFileError, match="refused.*pickled Python objects"):
        load_memmap_checked(tmp_path / "td")
    assert not marker.exists()
    TensorDict.load_memmap(tmp_path / "td", allow_pickle=True)  # the sidecar is real: a full load runs it
    assert marker.is_dir()


def test_training_state_rng_is_plain_and_round_trips(tmp_path):
    from drs_torchrl.runtime.checkpoint import rng_state, set_rng_state

    np.random.seed(3)
    np.random.normal()  # a cached gaussian in the state
    torch.save(rng_state(), tmp_path / "rng.pt")
    want = np.random.random(5)
    np.random.seed(99)
    set_rng_state(torch_load(tmp_path / "rng.pt", "rng"))
    assert np.array_equal(np.random.random(5), want)


@pytest.mark.parametrize(
    "target, ok",
    [
        ("torchrl.objectives.SACLoss", True),
        ("torch.optim.Adam", True),
        ("drs_torchrl.updaters.sac.make_sac_updater", True),
        ("torchrl.collectors.MultiAsyncCollector", True),
        ("os.system", False),
        ("builtins.exec", False),
        ("torch.load", False),
        ("torch.hub.load", False),
        ("tensordict.TensorDict.load_memmap", False),
        ("drs_torchrl.runtime.safe_files.convert_file", False),
        ("drs_torchrl.tools.study.main", False),
        ("torch.nn.Module.load_state_dict", False),
        ("torch.optim.${oc.env:X}", False),
        ("torch.optim._private", False),
    ],
)
def test_allowed_targets(target, ok):
    assert allowed_target(target) is ok


def test_a_users_own_module_is_allowed_only_when_the_user_names_it(monkeypatch):
    """docs/rewards.md: a reward builder of the user's own; a config cannot trust itself, the environment can."""
    cfg = {"reward": {"learner": {"_target_": "my_rewards.builders.my_learner"}}}
    with pytest.raises(UnsafeFileError, match="DRS_TRUSTED_TARGETS=your_module"):
        check_targets(cfg, "config.yaml")
    monkeypatch.setenv("DRS_TRUSTED_TARGETS", "other, my_rewards")
    check_targets(cfg, "config.yaml")
    assert not allowed_target("my_rewards.builders.load_pickle")  # never a loader, trusted or not
    assert not allowed_target("my_rewardsX.builders.my_learner")  # a prefix is a module, not a string start


def test_every_committed_run_config_passes_the_target_check():
    configs = sorted(REPO.glob("results/**/config.yaml"))
    assert len(configs) > 100
    for f in configs:
        check_targets(OmegaConf.load(f), f)


def run_eval(capsys, *args: str) -> tuple[int, str]:
    """drs-eval in this process: (exit code, stderr)."""
    from drs_torchrl.apps.evaluate import main as drs_eval

    try:
        code = drs_eval(list(args))
    except SystemExit as exc:
        code = exc.code
    return code, capsys.readouterr().err.strip()


def _run_copy(tmp_path: Path) -> Path:
    run = tmp_path / "run"
    shutil.copytree(RECORD, run)
    return run


def test_a_config_naming_other_code_is_refused_by_evaluation_and_resume(tmp_path, cli, capsys):
    run = _run_copy(tmp_path)
    cfg = OmegaConf.load(run / "config.yaml")
    cfg.algo.optim._target_ = "os.system"
    OmegaConf.save(cfg, run / "config.yaml")
    code, err = run_eval(capsys, str(run), "--episodes", "1")
    assert code == 2 and "\n" not in err and "algo.optim._target_ is 'os.system'" in err
    code, err = cli("learn", f"resume={run}")
    assert (
        code == 2
        and "\n" not in err.strip()
        and "refused: algo.optim._target_" in err.replace(f"{run}/config.yaml: ", "")
    )


@pytest.mark.sim
@pytest.mark.slow
def test_drs_eval_refuses_a_crafted_policy_with_exit_2(tmp_path, capsys):
    run = _run_copy(tmp_path)
    marker = tmp_path / "ran"
    good = torch.load(run / "policy.pt", weights_only=True)
    torch.save({**good, "extra": Payload(marker)}, run / "policy.pt")
    code, err = run_eval(capsys, str(run), "--episodes", "1")
    assert code == 2 and "\n" not in err and "refused" in err and not marker.exists()
    assert not list(run.glob("eval_*.json"))  # no report of a policy it did not load


@pytest.mark.sim
@pytest.mark.slow
def test_resume_refuses_a_crafted_training_state_with_exit_2(tmp_path, cli):
    from budgets import tiny

    run = tmp_path / "run"
    code, err = cli("learn", *tiny(frames=256, checkpoint_every=128, eval_episodes=0), f"hydra.run.dir={run}")
    assert code == 0, err
    state = run / "checkpoints" / "state" / "trainer.pt"
    payload = torch.load(state, weights_only=True)  # what this version writes loads weights-only
    marker = tmp_path / "ran"
    torch.save({**payload, "extra": Payload(marker)}, state)
    before = sorted(p.name for p in run.rglob("*"))
    code, err = cli("learn", f"resume={run}", "total_frames=512")
    assert code == 2 and "\n" not in err.strip() and "refused: this training state holds" in err, err
    assert not marker.exists() and sorted(p.name for p in run.rglob("*")) == before


def test_drs_convert_rewrites_a_trusted_state_of_an_earlier_version(tmp_path, capsys):
    from drs_torchrl.runtime.checkpoint import rng_state
    from drs_torchrl.runtime.safe_files import main as drs_convert

    old_rng = {**rng_state(), "numpy": np.random.get_state()}  # how versions before 0.2 saved it (an ndarray)
    f = tmp_path / "trainer.pt"
    torch.save({"format": "drs-torchrl/training-state", "rng": old_rng, "n": np.int64(3)}, f)
    with pytest.raises(UnsafeFileError, match="numpy"):
        torch_load(f, "training state")
    assert drs_convert([str(f)]) == 0
    new = torch_load(f, "training state")
    assert new["n"] == 3 and torch.equal(new["rng"]["numpy"][1], torch.from_numpy(old_rng["numpy"][1].astype(np.int64)))
    assert (tmp_path / "trainer.pt.orig").is_file()
    assert "converted" in capsys.readouterr().out
    assert drs_convert([str(f)]) == 0 and "already safe" in capsys.readouterr().out
    # a file holding something drs-torchrl never wrote is not converted
    crafted(tmp_path / "evil.pt", tmp_path / "ran")
    with pytest.raises(SystemExit) as info:
        drs_convert([str(tmp_path / "evil.pt")])
    assert info.value.code == 2 and "not converted" in capsys.readouterr().err
    assert not (tmp_path / "ran").exists()  # converting reads weights-only too: nothing in the file ran


def test_old_rng_form_still_resumes_after_conversion(tmp_path):
    """A converted state's numpy RNG (a tuple holding an int64 tensor) is what set_rng_state restores."""
    from drs_torchrl.runtime.checkpoint import set_rng_state

    np.random.seed(5)
    old = np.random.get_state()
    want = np.random.random(3)
    torch.save({"rng": {"torch": torch.get_rng_state(), "numpy": old, "python": __import__("random").getstate()}},
               tmp_path / "s.pt")  # fmt: skip
    convert_file(tmp_path / "s.pt")
    set_rng_state(torch_load(tmp_path / "s.pt", "state")["rng"])
    assert np.array_equal(np.random.random(3), want)


def test_reward_checkpoint_that_is_a_directory_names_the_file_inside(tmp_path):
    from drs_torchrl.transforms.reward import RewardCheckpointError, read_reward_checkpoint

    with pytest.raises(RewardCheckpointError, match=r"is a directory; pass the file: reward.checkpoint=.*reward\.pt"):
        read_reward_checkpoint(RECORD)


def test_a_non_ascii_path_gets_a_quoting_hint(cli):
    code, err = cli("reuse", "reward=drs", "reward.checkpoint=/tmp/müde/reward.pt")
    assert code == 2 and """'reward.checkpoint="/tmp/müde/reward.pt"'""" in err and "\n" not in err.strip()


def test_drs_eval_does_not_write_into_a_run_another_process_holds(tmp_path, capsys):
    import subprocess
    import sys

    run = _run_copy(tmp_path)
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            f"from drs_torchrl.runtime.rundir import lock_run_dir; lock_run_dir({str(run)!r}); input()",
        ],
        stdin=subprocess.PIPE,
        env={**os.environ, "PYTHONPATH": str(REPO / "src")},
    )
    try:
        for _ in range(100):
            if (run / ".drs-lock").is_file() and (run / ".drs-lock").read_text().strip():
                break
            __import__("time").sleep(0.1)
        code, err = run_eval(capsys, str(run), "--episodes", "1")
        assert code == 2 and "another process" in err and "--out" in err and "\n" not in err
    finally:
        holder.communicate(b"\n", timeout=30)
    assert not list(run.glob("eval_*.json"))
    assert json.loads((run / "summary.json").read_text())  # the run's files untouched
