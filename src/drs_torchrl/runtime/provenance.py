"""Which code produced a run: the git commit of the checkout the package was imported from.

Studies run from a worktree pinned to a commit (docs: studies); each run's ``summary.json`` records that
commit, and whether the checkout had uncommitted changes, so a result names the code behind it.
"""

from __future__ import annotations

import functools
import subprocess
from pathlib import Path


@functools.cache
def code_version() -> dict:
    """``{"commit": sha or None, "dirty": bool or None, "version": package version}``; commit and dirty are
    None where the package is not imported from a git checkout (an installed wheel)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        pkg_version = version("drs-torchrl")
    except PackageNotFoundError:
        pkg_version = None
    here = Path(__file__).resolve().parent

    def git(*args):
        try:
            out = subprocess.run(["git", "-C", str(here), *args], capture_output=True, text=True, timeout=10)
        except (OSError, subprocess.SubprocessError):
            return None
        return out.stdout.strip() if out.returncode == 0 else None

    commit = git("rev-parse", "HEAD")
    status = git("status", "--porcelain", "--untracked-files=no", "--", ":/src", ":/conf") if commit else None
    return {"commit": commit, "dirty": None if status is None else bool(status), "version": pkg_version}
