"""drs-compare: grouping runs by config keys and averaging their curves over seeds.

The aggregation is checked on hand-written run folders (CSV + config.yaml) whose means and stds
are known; ``test_cli.py`` runs drs-compare on real drs-learn output.
"""

import csv
from pathlib import Path

import numpy as np
import pytest

from drs_torchrl.tools.comparison import CompareError, compare, group_style, main


def make_run(root: Path, name: str, reward: str, seed: int, success: list[float], reach1: list[float], interval=1000):
    d = root / name
    d.mkdir(parents=True)
    (d / "config.yaml").write_text(
        f"env:\n  family: pick_cube\n  split: test\nreward:\n  name: {reward}\nseed: {seed}\nphase: reuse\n"
    )
    steps = [interval * (i + 1) for i in range(len(success))]
    with (d / "eval.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["step", "episodes", "success_rate", "reach_stage_1", "reach_stage_2"])
        for s, y, r in zip(steps, success, reach1):
            w.writerow([s, 10, y, r, y])
    with (d / "train.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["step", "success_rate", "reach_stage_1", "reach_stage_2"])
        for s, y, r in zip(steps, success, reach1):
            w.writerow([s, y / 2, r, y / 2])
    return d


def rows_of(path: Path):
    return list(csv.DictReader(path.open()))


def test_groups_by_reward_and_averages_over_seeds(tmp_path):
    a0 = make_run(tmp_path, "a0", "drs", 0, [0.0, 0.4, 0.8], [0.2, 0.6, 1.0])
    a1 = make_run(tmp_path, "a1", "drs", 1, [0.0, 0.2, 0.6], [0.0, 0.4, 1.0])
    a2 = make_run(tmp_path, "a2", "drs", 2, [0.2, 0.6], [0.4, 0.8])  # interrupted: one eval fewer
    b0 = make_run(tmp_path, "b0", "semi_sparse", 0, [0.0, 0.0, 0.1], [0.0, 0.1, 0.2])
    paths = compare([a0, a1, a2, b0], tmp_path / "out")
    assert all(p.is_file() and p.stat().st_size > 0 for p in paths.values())

    rows = [r for r in rows_of(paths["csv"]) if r["source"] == "eval" and r["metric"] == "success_rate"]
    drs = {int(r["step"]): r for r in rows if r["group"] == "drs"}
    assert [int(drs[s]["n"]) for s in (1000, 2000, 3000)] == [3, 3, 2]
    np.testing.assert_allclose(float(drs[2000]["mean"]), np.mean([0.4, 0.2, 0.6]))
    np.testing.assert_allclose(float(drs[2000]["std"]), np.std([0.4, 0.2, 0.6]))
    np.testing.assert_allclose(float(drs[3000]["mean"]), 0.7)  # the runs that reached 3000 steps only
    semi = [r for r in rows if r["group"] == "semi_sparse"]
    assert [float(r["std"]) for r in semi] == [0.0, 0.0, 0.0] and [int(r["n"]) for r in semi] == [1, 1, 1]
    # the earlier stages get their own curves, from eval and from training episodes; the last
    # stage is success, drawn once
    metrics = {(r["source"], r["metric"]) for r in rows_of(paths["csv"])}
    assert metrics == {
        ("eval", "success_rate"),
        ("eval", "reach_stage_1"),
        ("train", "success_rate"),
        ("train", "reach_stage_1"),
    }

    md = paths["md"].read_text()
    drs_line = next(line for line in md.splitlines() if line.startswith("| drs "))
    # final success per run, its mean +- std, and the shortest run's length
    assert (
        "0.80, 0.60, 0.60" in drs_line
        and f"{np.mean([0.8, 0.6, 0.6]):.2f} +- {np.std([0.8, 0.6, 0.6]):.2f}" in drs_line
    )
    assert "| 2000 |" in drs_line and "3 (0, 1, 2)" in drs_line


def test_auc_and_first_step_past_half_have_known_values(tmp_path):
    # a: 0, 0.4, 0.8, 1.0 at 1k..4k; b: 0, 0.8, 0.8 (shorter); c: another group, 0.2 throughout
    a = make_run(tmp_path, "a", "drs", 0, [0.0, 0.4, 0.8, 1.0], [0, 0, 0, 0])
    b = make_run(tmp_path, "b", "drs", 1, [0.0, 0.8, 0.8], [0, 0, 0])
    c = make_run(tmp_path, "c", "sparse", 0, [0.2, 0.2, 0.2, 0.2], [0, 0, 0, 0])
    from drs_torchrl.tools.comparison import group_runs, load_run, summary_rows

    rows = {r["group"]: r for r in summary_rows(group_runs([load_run(x) for x in (a, b, c)]))}
    # every AUC runs to the shortest evaluated run of the comparison (3k), from the first evaluation (1k)
    assert rows["drs"]["auc_horizon"] == 3000
    auc_a = ((0.0 + 0.4) / 2 + (0.4 + 0.8) / 2) / 2  # 0.4
    auc_b = ((0.0 + 0.8) / 2 + (0.8 + 0.8) / 2) / 2  # 0.6
    np.testing.assert_allclose(rows["drs"]["auc_mean"], np.mean([auc_a, auc_b]))
    np.testing.assert_allclose(rows["drs"]["auc_std"], np.std([auc_a, auc_b]))
    np.testing.assert_allclose(rows["sparse"]["auc_mean"], 0.2)
    # the mean over both seeds is 0.6 at 2k (b alone would pass at 2k too, a alone at 3k)
    assert rows["drs"]["first_step_0_5"] == 2000 and rows["sparse"]["first_step_0_5"] is None
    md = compare([a, b, c], tmp_path / "out")["md"].read_text()
    assert "success AUC to 3k" in md
    assert "| 0.500 +- 0.100 | 2k |" in md and "| 0.200 +- 0.000 | not by 4k |" in md
    # training episodes: reach_stage_1 is 0 throughout, success (the rolling train column, half the eval's) never 0.5
    assert "| drs | not by 3k | not by 3k |" in md


def test_a_run_with_one_evaluation_does_not_set_the_auc_horizon(tmp_path):
    # ORIL's phase 1 stops after one evaluation (its reward is fixed before the first step): it has no
    # curve to integrate, and the other runs keep their horizon (3k) instead of collapsing to 1k
    a = make_run(tmp_path, "a", "drs", 0, [0.0, 0.4, 0.8, 1.0], [0, 0, 0, 0])
    b = make_run(tmp_path, "b", "sparse", 0, [0.2, 0.2, 0.2], [0, 0, 0])
    o = make_run(tmp_path, "o", "oril", 0, [0.0], [0.0])
    from drs_torchrl.tools.comparison import group_runs, load_run, summary_rows

    rows = {r["group"]: r for r in summary_rows(group_runs([load_run(x) for x in (a, b, o)]))}
    assert rows["drs"]["auc_horizon"] == 3000
    np.testing.assert_allclose(rows["drs"]["auc_mean"], 0.4)
    assert np.isnan(rows["oril"]["auc_mean"]) and rows["oril"]["final"] == [0.0]
    # only single-evaluation runs: the horizon is still their step (nothing to integrate)
    rows = summary_rows(group_runs([load_run(o)]))
    assert rows[0]["auc_horizon"] == 1000 and np.isnan(rows[0]["auc_mean"])


def test_training_table_gives_the_first_step_each_stage_passes_half(tmp_path):
    a = make_run(tmp_path, "a", "drs", 0, [0.0, 0.4, 1.0], [0.2, 0.6, 1.0])  # train: stage 1 = reach1, success = y / 2
    b = make_run(tmp_path, "b", "drs", 1, [0.0, 0.0, 1.0], [0.4, 0.8, 1.0])
    md = compare([a, b], tmp_path / "out")["md"].read_text()
    # stage 1: mean 0.3, 0.7, 1.0 -> 2k; success: mean 0, 0.1, 0.5 -> 3k
    assert "| group | reached stage 1 (is_grasped) | success |" in md and "| drs | 2k | 3k |" in md
    # runs with other stages (an ablation's env.stages) in the same table: the columns keep their numbers only
    c = make_run(tmp_path, "c", "drs", 2, [0.0, 0.0, 1.0], [0.4, 0.8, 1.0])
    (c / "config.yaml").write_text(
        (c / "config.yaml")
        .read_text()
        .replace("  split: test\n", "  split: test\n  stages: [is_obj_placed, success]\n")
    )
    md = compare([a, c], tmp_path / "out2")["md"].read_text()
    assert "| group | reached stage 1 | success |" in md


def test_first_step_counts_only_steps_every_seed_reached(tmp_path):
    a = make_run(tmp_path, "a", "drs", 0, [0.0, 0.2, 1.0], [0, 0, 0])
    b = make_run(tmp_path, "b", "drs", 1, [0.0, 0.2], [0, 0])  # interrupted before 3k
    from drs_torchrl.tools.comparison import first_step_over, load_run

    assert first_step_over([load_run(a), load_run(b)]) is None  # a alone passes at 3k: not the group's mean
    assert first_step_over([load_run(a)]) == 3000


def test_a_step_logged_twice_counts_once(tmp_path):
    a = make_run(tmp_path, "a", "drs", 0, [0.0, 0.4], [0.0, 0.4])
    with (a / "eval.csv").open("a", newline="") as f:  # a resumed run repeats its last step
        csv.writer(f).writerow([2000, 10, 0.6, 0.6, 0.6])
    b = make_run(tmp_path, "b", "drs", 1, [0.0, 0.2], [0.0, 0.2])
    rows = [
        r
        for r in rows_of(compare([a, b], tmp_path / "out")["csv"])
        if r["source"] == "eval" and r["metric"] == "success_rate"
    ]
    assert [(int(r["step"]), int(r["n"])) for r in rows] == [(1000, 2), (2000, 2)]
    np.testing.assert_allclose(float(rows[1]["mean"]), 0.4)  # (0.6 + 0.2) / 2: the later row of a


def test_group_by_several_keys(tmp_path):
    a = make_run(tmp_path, "a", "drs", 0, [0.1], [0.1])
    b = make_run(tmp_path, "b", "drs", 1, [0.3], [0.3])
    paths = compare([a, b], tmp_path / "out", group_by=("env.split", "seed"))
    groups = {r["group"] for r in rows_of(paths["csv"])}
    assert groups == {"test 0", "test 1"}


def test_bad_inputs_name_what_is_wrong(tmp_path, capsys):
    a = make_run(tmp_path, "a", "drs", 0, [0.1], [0.1])
    with pytest.raises(CompareError, match="no key 'reward.nmae'"):
        compare([a], tmp_path / "out", group_by=("reward.nmae",))
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main([str(empty), "--out", str(tmp_path / "out2")]) == 2
    assert "has no train.csv" in capsys.readouterr().err
    assert not (tmp_path / "out2").exists()


def test_a_run_given_twice_is_refused_not_counted_as_two_seeds(tmp_path, capsys, monkeypatch):
    """A shell glob that names a run twice (``runs/*/ runs/sparse*``) had made one run "2 (0, 0)" seeds."""
    a = make_run(tmp_path, "a", "sparse", 0, [0.5], [0.5])
    monkeypatch.chdir(tmp_path)
    assert main(["a", str(a) + "/", "--out", "out"]) == 2
    assert (
        capsys.readouterr().err
        == f"drs-compare: error: run directory {a} is given twice (as a and {a}): give each run once\n"
    )
    with pytest.raises(CompareError, match="is given twice: give each run once"):
        compare([a, a], tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_groups_beyond_ten_keep_distinct_styles():
    """Matplotlib's colour cycle repeats after 10; the pick study plots 14 groups and must tell them apart."""
    styles = [(s["color"], s["linestyle"]) for s in map(group_style, range(40))]
    assert len(set(styles)) == 40
    assert group_style(0) == {"color": "C0", "linestyle": "-"} and group_style(13)["linestyle"] == "--"


def test_a_run_a_success_rule_ended_early_is_held_at_its_last_evaluation_and_sets_no_horizon(tmp_path):
    """eval.stop_at_success ends a run once it succeeds: it must not cut every group's AUC to its few steps, and its
    group's mean must not lose it at the steps it did not run."""
    import json

    a = make_run(tmp_path, "a", "drs", 0, [0.0, 0.9, 0.9], [0, 0, 0])  # stopped at 3k by the rule
    (a / "summary.json").write_text(json.dumps({"frames": 3000, "stopped_at_eval_success": {"frames": 3000}}))
    b = make_run(tmp_path, "b", "drs", 1, [0.0, 0.0, 0.0, 0.0, 0.2, 0.8], [0] * 6)
    c = make_run(tmp_path, "c", "sparse", 0, [0.0, 0.1, 0.1, 0.1, 0.1, 0.1], [0] * 6)
    from drs_torchrl.tools.comparison import group_runs, load_run, summary_rows

    runs = [load_run(x) for x in (a, b, c)]
    assert [r.stopped_at for r in runs] == [3000, None, None]
    rows = {r["group"]: r for r in summary_rows(group_runs(runs))}
    assert rows["drs"]["auc_horizon"] == 6000  # set by the runs that ran their budget, not a's 3k
    auc_a = ((0.0 + 0.9) / 2 + 0.9 * 4) / 5  # 0.9 held from 3k to 6k
    auc_b = (0.0 + 0.0 + 0.0 + 0.1 + 0.5) / 5
    np.testing.assert_allclose(rows["drs"]["auc_mean"], np.mean([auc_a, auc_b]))
    assert rows["drs"]["final"] == [0.9, 0.8] and rows["drs"]["last3_mean"] == pytest.approx((0.6 + 1 / 3) / 2)
    # the group's mean passes 0.5 at 5k (0.9 held, 0.2), a step a did not run: without a's held value no step after
    # 3k would count (not every run of the group has it)
    assert rows["drs"]["first_step_0_5"] == 5000 and rows["drs"]["carried"] == [("a", 3000)]
    md = compare([a, b, c], tmp_path / "out")["md"].read_text()
    assert "Ended early by a success rule" in md and "`a` at 3k" in md
