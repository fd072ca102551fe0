"""The wheel works outside the repository: it carries conf/ as drs_torchrl/conf, conf_dir() finds it there in an
installed layout, and its metadata has one version, the license, every console script and one OpenCV."""

import email
import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel of this checkout, built from a copy of what a build reads (so the tree gets no build/ folder)."""
    src = tmp_path_factory.mktemp("checkout")
    for name in ("pyproject.toml", "setup.py", "README.md", "LICENSE"):
        shutil.copy(REPO / name, src / name)
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info", "*.pyc")
    shutil.copytree(REPO / "conf", src / "conf", ignore=ignore)
    shutil.copytree(REPO / "src", src / "src", ignore=ignore)
    out = tmp_path_factory.mktemp("dist")
    p = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(out), "."],
        cwd=src,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    (whl,) = out.glob("drs_torchrl-*.whl")
    return whl


def test_the_wheel_carries_every_config_file(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    confs = {f"drs_torchrl/conf/{p.relative_to(REPO / 'conf').as_posix()}" for p in (REPO / "conf").rglob("*.yaml")}
    assert confs and confs <= names, sorted(confs - names)
    modules = {
        f"drs_torchrl/{p.relative_to(REPO / 'src/drs_torchrl').as_posix()}"
        for p in (REPO / "src/drs_torchrl").rglob("*.py")
        if "__pycache__" not in p.parts
    }
    assert modules <= names, sorted(modules - names)


def test_the_wheel_metadata_has_one_version_the_license_every_script_and_one_opencv(wheel):
    import drs_torchrl

    z = zipfile.ZipFile(wheel)
    info = next(n.split("/")[0] for n in z.namelist() if n.endswith(".dist-info/METADATA"))
    meta = email.message_from_bytes(z.read(f"{info}/METADATA"))
    assert meta["Version"] == drs_torchrl.__version__ and wheel.name.startswith(
        f"drs_torchrl-{drs_torchrl.__version__}-"
    )
    assert meta["License-Expression"] == "MIT" and f"{info}/licenses/LICENSE" in z.namelist()
    opencv = [r for r in meta.get_all("Requires-Dist") if r.lower().startswith("opencv")]
    assert len(opencv) == 1, opencv
    scripts = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]
    entry_points = z.read(f"{info}/entry_points.txt").decode()
    assert "drs-probe" in scripts and all(f"{name} = {target}" in entry_points for name, target in scripts.items())


@pytest.mark.slow
def test_conf_dir_finds_the_configs_inside_an_installed_package(wheel, tmp_path):
    """Unpacked as pip installs it, outside the repository: the apps' config directory is the package's own."""
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    code = (
        "import drs_torchrl, drs_torchrl.apps.cli as apps, drs_torchrl.apps.reward_registry as rewards\n"
        "from hydra import compose, initialize_config_dir\n"
        "print(drs_torchrl.__file__); print(apps.conf_dir()); print(len(rewards.available_rewards()))\n"
        "with initialize_config_dir(config_dir=apps.conf_dir(), version_base=None):\n"
        "    print(compose('learn').env.family)\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "DRS_CONF_DIR"}
    env["PYTHONPATH"] = str(site)  # ahead of the checkout's editable install
    p = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    module, conf, n_rewards, family = p.stdout.split()[-4:]
    assert Path(module).parent == site / "drs_torchrl"
    assert Path(conf) == site / "drs_torchrl" / "conf"
    assert int(n_rewards) >= 8  # the reward registry is read from the package's conf/reward
    assert family
