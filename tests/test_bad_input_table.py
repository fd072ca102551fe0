"""results/bad_inputs/README.md is what results/bad_inputs/bad_input_table.py gets now: every bad input of every console
script is refused (non-zero exit) without touching an existing run, and the committed table is current."""

import re
import subprocess
import sys
from pathlib import Path

import pytest


ROOT = Path(__file__).resolve().parents[1]


def rows(text: str) -> dict[str, list[str]]:
    """bad input -> [exit code, message, one line, untouched]."""
    out = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split(" | ")]
        if len(cells) == 5 and (cells[1].lstrip("-").isdigit() or cells[2].startswith("not run:")):
            out[cells[0]] = cells[1:]
    return out


@pytest.fixture(scope="module")
def table(tmp_path_factory):
    out = tmp_path_factory.mktemp("table") / "README.md"
    p = subprocess.run(
        [sys.executable, str(ROOT / "results" / "bad_inputs" / "bad_input_table.py"), "--out", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=1500,
    )
    assert out.is_file(), p.stderr[-3000:]
    return p, rows(out.read_text())


@pytest.mark.sim
@pytest.mark.slow
def test_every_bad_input_is_refused_and_loses_nothing(table):
    p, got = table
    assert len(got) >= 50
    bad = {name: r for name, r in got.items() if r[0] == "0" or r[3] == "NO"}
    assert not bad, bad
    assert p.returncode == 0, p.stdout[-3000:]


def message_kind(message: str) -> str:
    """A message's first words with paths and numbers blanked: what refused the input, not its temporary details."""
    message = re.sub(r"/\S+", "PATH", message)
    return " ".join(re.sub(r"\d+", "N", message).split()[:6])


@pytest.mark.sim
@pytest.mark.slow
def test_the_committed_table_is_current(table):
    """Same cases, exit codes, verdicts and kinds of message as the committed table (its messages hold temporary
    paths, pids and sizes, so only their first words are compared: a row whose refusal came from another check, as
    the truncated training state's once did, is stale)."""
    _, got = table
    committed = rows((ROOT / "results" / "bad_inputs" / "README.md").read_text())
    assert set(got) == set(committed)
    ran = [n for n in got if got[n][0] != "-" and committed[n][0] != "-"]  # "-": not run on that machine (no tmpfs)
    assert {n: (got[n][0], message_kind(got[n][1]), got[n][2], got[n][3]) for n in ran} == {
        n: (committed[n][0], message_kind(committed[n][1]), committed[n][2], committed[n][3]) for n in ran
    }


def test_message_kind_tells_a_refusal_from_another_check():
    stale = (
        "drs-learn: error: demos.stage_buffers=true is a setting of the demonstrations in demos.path, which is not set"
    )
    fixed = (  # the refusal this case gets now
        "drs-learn: error: /tmp/drs-bad-x/case29/good/checkpoints/state/trainer.pt cannot be read (corrupt or truncated"
    )
    assert message_kind(stale) != message_kind(fixed)
    assert message_kind(fixed) == message_kind(fixed.replace("/tmp/drs-bad-x/case29", "/tmp/drs-bad-y/case30"))


@pytest.mark.parametrize(
    "case,pattern",
    [
        (
            "two runs started at once into one directory",
            r"^drs-learn: error: \S+/run is being written by another process \(pid \d+\); .*choose another hydra\.run\.dir$",
        ),
        (
            "resume of a run whose training state is truncated",
            r"^drs-learn: error: \S+/checkpoints/state/trainer\.pt cannot be read \(corrupt or truncated.*\); the run "
            r"cannot continue from it: start it afresh with overwrite=true",
        ),
        ("CUDA asked for, none present", r"^drs-learn: error: device=cuda was requested but CUDA is not available"),
        (
            "GPU simulation asked for, no CUDA",
            r"^drs-learn: error: sim_backend='physx_cuda' was requested but CUDA is not available",
        ),
    ],
)
@pytest.mark.sim
@pytest.mark.slow
def test_issue_48_cases_are_one_line_with_the_fix(table, case, pattern):
    """Two writers, a damaged training state, a device the machine lacks (none visible to the case): one line naming
    the path or value and what to do. The other refusals' messages are pinned once elsewhere: a full disk (its own
    drs-learn run, test_cli_safety.py); in the test's process, a damaged config.yaml, an unknown env id, ``--video``
    naming a file and ``drs-demos --out`` naming a folder (test_cli_safety.py), an unknown reward (test_cli.py,
    test_rundir.py), a reward of another layout and a missing reward checkpoint (test_cli.py)."""
    _, got = table
    code, message, one_line, untouched = got[case]
    assert code == "2" and one_line == "yes" and untouched == "yes", got[case]
    assert re.search(pattern, message), message
