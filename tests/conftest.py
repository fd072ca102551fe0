import os

import pytest

os.environ.setdefault("HYDRA_FULL_ERROR", "0")


@pytest.fixture(scope="session")
def pick_cube():
    from drs_torchrl.tasks import get_family

    return get_family("pick_cube")
