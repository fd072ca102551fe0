"""Demonstrations: recorded with ManiSkill's motion planner, saved, loaded, checked against the task."""
import json

import pytest
import torch
from tensordict import TensorDict

from drs_torchrl.data import StageBuffers
from drs_torchrl.demos import DemoError, check_demos, load_demos, record_demos, save_demos


@pytest.fixture(scope="module")
def demo_dir(tmp_path_factory, pick_cube):
    states, meta = record_demos(pick_cube, "cube_2cm", 3, seed=10, progress=False)
    return save_demos(states, meta, tmp_path_factory.mktemp("demos") / "pc.demos")


@pytest.mark.sim
def test_recorded_demos_succeed_and_round_trip(demo_dir, pick_cube):
    episodes, meta = load_demos(demo_dir)
    assert len(episodes) == meta["episodes"] == 3
    assert meta["shapes"] == {"observation": 42, "stage_indicators": 3}
    for ep, n in zip(episodes, meta["lengths"]):
        assert ep.shape[0] == n
        assert bool(ep["success"][-1]) and not bool(ep["success"][:-1].any())  # cut at first success
        assert int(ep["stage"][-1]) == 3
        assert ep["step"].tolist() == list(range(n))
    check_demos(meta, pick_cube, {"observation": 42, "stage_indicators": 3})
    sb = StageBuffers(3, ["observation", "stage_indicators"], capacity=1000)
    for ep in episodes:
        assert sb.add_trajectory(TensorDict({"next": ep}, ep.shape), demo=True) == 3
    assert sb.stage_counts().tolist() == [0, 0, 0, sum(meta["lengths"])]


@pytest.mark.sim
def test_mismatching_demos_are_named(demo_dir, pick_cube):
    _, meta = load_demos(demo_dir)
    with pytest.raises(DemoError) as e:
        check_demos({**meta, "family": "stack_cube"}, pick_cube, {"observation": 48, "stage_indicators": 3})
    assert "'stack_cube'" in str(e.value) and "size 42" in str(e.value) and "size 48" in str(e.value)
    with pytest.raises(DemoError, match="stage indicators"):
        check_demos({**meta, "stage_keys": ["success"]}, pick_cube, {"observation": 42})


def test_bad_demo_directories(tmp_path):
    with pytest.raises(DemoError, match="no meta.json"):
        load_demos(tmp_path)
    states = TensorDict({"observation": torch.zeros(2, 3), "episode": torch.zeros(2, dtype=torch.long)}, [2])
    meta = {"format": "drs-torchrl/demos", "version": 99}
    save_demos(states, meta, tmp_path / "future.demos")
    with pytest.raises(DemoError, match="newer"):
        load_demos(tmp_path / "future.demos")
    save_demos(states, {**meta, "version": 1}, tmp_path / "broken.demos")
    for f in (tmp_path / "broken.demos" / "states").rglob("*.memmap"):
        f.write_bytes(b"")
    with pytest.raises(DemoError, match="cannot be read"):
        load_demos(tmp_path / "broken.demos")
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "meta.json").write_text(json.dumps({"format": "something-else"}))
    with pytest.raises(DemoError, match="unknown format"):
        load_demos(tmp_path / "other")
