import os

import pytest

os.environ.setdefault("HYDRA_FULL_ERROR", "0")
if os.environ.get("PYTEST_XDIST_WORKER"):
    # `pytest -n N` (the README's test command): N workers side by side, each at one thread, the CLI runs
    # they start included (a 2-thread process beside another collapses on a 2-core machine)
    os.environ["OMP_NUM_THREADS"] = "1"
    os.environ["MKL_NUM_THREADS"] = "1"
    import torch

    torch.set_num_threads(1)


@pytest.fixture(scope="session")
def pick_cube():
    from drs_torchrl.tasks import get_family

    return get_family("pick_cube")


@pytest.fixture
def cli(monkeypatch, capsys):
    """``cli("learn", *overrides) -> (exit code, stderr)``: the drs-learn / drs-reuse / drs-maze / drs-quickstart Hydra app in this
    process, for commands that stop before simulating (bad input). The same app, config composition
    and error handling as the console scripts, without starting an interpreter (each costs ~10 s
    here); the runs that simulate keep their subprocess. Whatever the app changes process-wide
    (environment, warning filters, streams) is put back."""
    import sys
    import warnings

    def call(app: str, *args: str) -> tuple[int, str]:
        import importlib

        apps = {
            "learn": "apps.cli:learn_main",
            "reuse": "apps.cli:reuse_main",
            "maze": "apps.maze:main",
            "quickstart": "tools.quickstart:main",
        }
        module, name = apps[app].split(":")  # imported when called: drs-maze imports torch at module level
        main = getattr(importlib.import_module(f"drs_torchrl.{module}"), name)
        env, filters, streams = dict(os.environ), warnings.filters[:], (sys.stdout, sys.stderr)
        monkeypatch.setattr(sys, "argv", [f"drs-{app}", *args])
        code = 0
        try:
            main()
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        finally:
            from hydra.core.global_hydra import GlobalHydra

            GlobalHydra.instance().clear()  # so that compose() in later tests starts clean
            os.environ.clear()
            os.environ.update(env)
            warnings.filters[:] = filters
            sys.stdout, sys.stderr = streams
        return code, capsys.readouterr().err

    return call
