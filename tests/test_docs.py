"""The documentation site builds in strict mode, so the README's test command checks the docs too.

``mkdocs build --strict`` fails on a broken link between pages, a page missing from the nav or the disk, an
anchor that does not exist, an API docstring that does not render, a figure of ``results/`` a page shows that is
not in the repository, and a console script whose ``--help`` cannot be rendered (``docs/hooks/reference.py``).
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    if importlib.util.find_spec("mkdocs") is None:
        pytest.fail("mkdocs is not installed: install the docs extra (pip install -e '.[docs]'; bin/setup.sh does)")
    out = tmp_path_factory.mktemp("site")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, f"mkdocs build --strict failed:\n{proc.stdout[-4000:]}\n{proc.stderr[-8000:]}"
    return out


@pytest.mark.slow
def test_site_builds_strict_with_every_page(site):
    for page in (
        "index.html",
        "getting-started.html",
        "concepts.html",
        "own-task.html",
        "recipe.html",
        "rewards.html",
        "studies.html",
        "claims.html",
        "performance.html",
        "reliability.html",
        "reference/cli.html",
        "reference/config.html",
        "api/transforms.html",
        "api/apps.html",
    ):
        assert (site / page).is_file(), page
    # a figure of the committed studies is carried into the site
    assert (site / "results" / "quickstart" / "seed0" / "quickstart.png").is_file()


@pytest.mark.slow
def test_cli_reference_has_every_console_script(site):
    text = (ROOT / "pyproject.toml").read_text()
    block = text.split("[project.scripts]", 1)[1].split("\n[", 1)[0]
    scripts = re.findall(r'^\s*([\w-]+)\s*=\s*"', block, re.M)
    assert scripts
    cli = (site / "reference" / "cli.html").read_text()
    for name in scripts:
        assert f'id="{name}"' in cli, f"{name} has no section on the command-line reference"
    assert "usage: drs-study" in cli and "Configuration groups" in cli  # an argparse and a Hydra --help rendered


@pytest.mark.slow
def test_config_reference_has_every_conf_file(site):
    config = (site / "reference" / "config.html").read_text()
    for f in sorted((ROOT / "conf").rglob("*.yaml")):
        label = f.name if f.parent == ROOT / "conf" else f"{f.parent.name}={f.stem}"
        assert label in config, f"conf/{f.relative_to(ROOT / 'conf')} is not on the config reference"


def test_reward_zoo_lists_every_reward():
    zoo = (ROOT / "docs" / "rewards.md").read_text()
    for f in sorted((ROOT / "conf" / "reward").glob("*.yaml")):
        assert f"| `{f.stem}` |" in zoo, f"reward={f.stem} has no row in docs/rewards.md"


def test_readme_setup_commands_are_what_ci_runs():
    readme = (ROOT / "README.md").read_text()
    ci = (ROOT / ".ci" / "run").read_text()
    test_command = "bin/setup.sh && .venv/bin/ruff check . && .venv/bin/ruff format --check . && .venv/bin/python -m pytest -q -n auto"
    assert test_command in ci
    assert test_command in readme and "bin/setup.sh && bin/drs-quickstart" in readme
    assert '".[test,locomotion,docs]"' in (ROOT / "bin" / "setup.sh").read_text()
