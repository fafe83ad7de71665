"""The simulated campaign, made and processed once per test run (tests/campaign/__init__.py)."""

import os
from pathlib import Path

import pytest

from tests.campaign import make_processed, make_runs, shared_dir


@pytest.fixture(scope="session")
def shared_base(tmp_path_factory) -> Path:
    """A folder every xdist worker of this run sees (the parent of their own temp folders)."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


@pytest.fixture(scope="session")
def campaign_runs(shared_base) -> Path:
    """root/runs: a_north, b_east, c_damaged (log damaged), d_broken (log of noise)."""
    return shared_dir(shared_base, "campaign-runs", make_runs)


@pytest.fixture(scope="session")
def processed(shared_base, campaign_runs) -> Path:
    """root/out, root/returncode, root/stdout, root/stderr of `sisa campaign process`."""
    return shared_dir(shared_base, "campaign-processed",
                      lambda root: make_processed(root, campaign_runs / "runs"))
