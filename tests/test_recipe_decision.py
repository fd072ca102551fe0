"""The pre-registered decision rule of the recipe study (results/recipe/PREREGISTRATION.md), as results/recipe/decide.py
applies it, on a made-up record whose verdicts are known: DrS beats X, X beats DrS, no difference; the recipe works,
works partly, fails; a run not finished makes every verdict that needs it "not decidable yet"."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
DECIDE = REPO / "results" / "recipe" / "decide.py"
STEPS = list(range(20_000, 300_001, 20_000))
ARMS = ("drs-learn0", "drs-learn1", "sparse", "semi_sparse", "dense")


def write_run(folder: Path, name: str, final: float, ramp_from: int = 20_000, finished: bool = True) -> None:
    """A reuse run's record: success 0 before ``ramp_from``, rising linearly to ``final`` at 300k."""
    d = folder / "run_files" / name
    d.mkdir(parents=True)
    rows = ["step,episodes,success_rate"]
    for s in STEPS:
        rate = 0.0 if s < ramp_from else final * (s - ramp_from + 20_000) / (300_000 - ramp_from + 20_000)
        rows.append(f"{s},20,{rate:.4f}")
    (d / "eval.csv").write_text("\n".join(rows) + "\n")
    summary = {"frames": 300_032 if finished else 150_000, "interrupted": not finished}
    (d / "summary.json").write_text(json.dumps(summary))


def make_record(
    tmp_path: Path, finals: dict[str, list[float]], unfinished: str | None = None, late: tuple[str, ...] = ()
) -> Path:
    """A family's record: the study file's run list and one finished run per arm and seed (``late`` arms succeed
    only at the last evaluation)."""
    folder = tmp_path / "fam"
    runs = [{"name": "learn_s0", "app": "learn"}, {"name": "learn_s1", "app": "learn"}]
    for arm in ARMS:
        for seed, final in enumerate(finals[arm]):
            name = f"{arm}_s{seed}"
            runs.append({"name": name})
            write_run(folder, name, final, 300_000 if arm in late else 20_000, finished=name != unfinished)
    (folder / "study.yaml").write_text(yaml.safe_dump({"app": "reuse", "runs": runs}))
    return folder


def decide(folder: Path) -> str:
    out = subprocess.run([sys.executable, str(DECIDE), str(folder)], capture_output=True, text=True, check=True)
    assert (folder / "decision.md").read_text() == out.stdout
    return out.stdout


def test_the_rule_names_each_comparison_and_the_recipe_as_the_preregistration_says(tmp_path):
    text = decide(
        make_record(
            tmp_path,
            {
                "drs-learn0": [0.8, 0.9, 0.7],
                "drs-learn1": [0.6, 0.5, 0.0],  # 5 of 6 >= 0.5, each reward >= 2 of 3: works
                "sparse": [0.0, 0.0, 0.1],  # 0.58 below DrS: DrS beats sparse
                "semi_sparse": [0.5, 0.6, 0.5],  # within 0.2 of DrS (0.583): no difference
                "dense": [1.0, 1.0, 1.0],  # 0.42 above DrS, and a larger AUC: dense beats DrS
            },
        )
    )
    assert "**All runs finished: the verdicts are final.**" in text
    assert "DrS vs sparse: **DrS beats sparse**" in text
    semi = next(line for line in text.splitlines() if line.startswith("- DrS vs semi_sparse"))
    assert "**no difference**" in semi and "neither arm" not in semi  # both arms above the margin: a real tie
    assert "DrS vs dense: **dense beats DrS**" in text
    assert "**works** (5 of 6 DrS runs end at >= 0.5; per phase-1 reward 3 and 2 of 3)" in text


def test_a_final_margin_without_the_auc_is_no_difference(tmp_path):
    # DrS ends 0.3 above sparse, but sparse climbs from the start and DrS succeeds only at the last evaluation
    finals = {**{a: [0.0] * 3 for a in ARMS}, "sparse": [0.6] * 3, "drs-learn0": [0.9] * 3, "drs-learn1": [0.9] * 3}
    text = decide(make_record(tmp_path, finals, late=("drs-learn0", "drs-learn1")))
    assert "DrS vs sparse: **no difference** (final +0.30, AUC -" in text
    assert "**works** (6 of 6" in text


def test_the_recipe_fails_works_partly_and_the_case_the_rule_leaves_open(tmp_path):
    none = {a: [0.0] * 3 for a in ARMS}
    text = decide(make_record(tmp_path / "a", none))
    assert "**fails** (0 of 6" in text
    # every arm at 0.00: "no difference" by the rule, with the note that no arm could meet the margin
    assert "DrS vs dense: **no difference** (final +0.00, AUC +0.000); neither arm's mean final reaches 0.2" in text
    one = {**none, "drs-learn1": [0.0, 0.7, 0.0]}
    assert "**works partly** (1 of 6" in decide(make_record(tmp_path / "b", one))
    lopsided = {**none, "drs-learn0": [0.9, 0.9, 0.9], "drs-learn1": [0.9, 0.0, 0.0]}  # 4 of 6, but 3 + 1
    text = decide(make_record(tmp_path / "c", lopsided))
    assert "**works partly** (4 of 6 DrS runs end at >= 0.5; per phase-1 reward 3 and 1 of 3); the rule names" in text


def test_an_unfinished_run_keeps_its_arm_undecided(tmp_path):
    finals = {a: [0.0] * 3 for a in ARMS}
    text = decide(make_record(tmp_path, finals, unfinished="dense_s2"))
    assert "**Provisional: 1 of 15 reuse runs not finished** (dense_s2)" in text
    assert "DrS vs dense: not decidable yet" in text
    assert "DrS vs sparse: **no difference**" in text  # complete arms are compared
    text = decide(make_record(tmp_path / "b", finals, unfinished="drs-learn1_s0"))
    assert "The recipe: not decidable yet" in text and "DrS vs sparse: not decidable yet" in text


def test_a_margin_of_exactly_0_2_counts(tmp_path):
    """Successes are multiples of 1/20, so a difference of exactly 0.2 happens; in floating point these means differ by
    0.19999999999999998, which the rule's ">= 0.2" must still count (both directions)."""
    none = {a: [0.0] * 3 for a in ARMS}
    drs = {"drs-learn0": [0.4, 0.4, 0.3], "drs-learn1": [0.3, 0.3, 0.3]}  # mean 1/3
    text = decide(make_record(tmp_path / "a", {**none, **drs, "sparse": [0.15, 0.15, 0.1]}))  # mean 2/15
    assert "DrS vs sparse: **DrS beats sparse** (final +0.20" in text
    text = decide(make_record(tmp_path / "b", {**none, **drs, "dense": [0.55, 0.55, 0.5]}))  # mean 8/15
    assert "DrS vs dense: **dense beats DrS** (final -0.20" in text


def test_the_readme_columns_name_each_family_verdict(tmp_path):
    """``decide.py --readme``: one column per family, the rule's verdicts in its rows, arms not finished marked."""
    none = {a: [0.0] * 3 for a in ARMS}
    a = make_record(tmp_path / "a", {**none, "drs-learn0": [0.9] * 3, "drs-learn1": [0.8] * 3})
    b = make_record(tmp_path / "b", none, unfinished="dense_s2")
    out = subprocess.run(
        [sys.executable, str(DECIDE), "--readme", str(a), str(b)], capture_output=True, text=True, check=True
    ).stdout
    rows = {line.split(" | ")[0].strip("| "): line.split(" | ")[1:] for line in out.splitlines()[2:]}
    assert rows["DrS beats sparse"][0].startswith("**DrS beats sparse**; sparse 0.00")
    assert rows["DrS beats sparse"][1].startswith("**no difference** (no signal: both below 0.2); sparse 0.00")
    assert (
        rows["DrS beats dense (ManiSkill's dense reward, minus 1)"][1]
        == "not decidable yet; dense 0.00 [0.000] (2 of 3 runs so far) |"
    )
    recipe = next(v for k, v in rows.items() if k.startswith("the recipe works"))
    assert recipe == ["**works** (6 of 6 end at >= 0.5)", "**fails** (0 of 6 end at >= 0.5) |"]


def test_the_readme_claims_table_shows_the_committed_records_verdicts():
    """The README's pre-registered columns are what ``decide.py --readme`` makes of the committed records (re-run it
    after recording a run)."""
    folders = [REPO / "results" / "recipe" / f for f in ("stack_cube", "place_sphere")]
    out = subprocess.run(
        [sys.executable, str(DECIDE), "--readme", *map(str, folders)], capture_output=True, text=True, check=True
    ).stdout
    assert out in (REPO / "README.md").read_text(), "README.md's pre-registered columns are stale:\n" + out
