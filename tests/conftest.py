"""Shared fixtures, the markers of the test suite, and hypothesis's profile (the same examples
on every run: CI must not flake).

Markers (``pytest -m "not slow"`` gives quick feedback; CI runs everything):

* ``slow``: a test that takes more than a few seconds (full closed loops, studies);
* ``subprocess``: a test that starts the CLI or Python in a new process;
* ``ray``: a test that starts a local Ray cluster.
"""

from __future__ import annotations

import pytest
from hypothesis import settings

import hydroarm

settings.register_profile("hydroarm", derandomize=True, database=None)
settings.load_profile("hydroarm")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "slow: takes more than a few seconds (deselect with -m 'not slow')")
    config.addinivalue_line("markers", "subprocess: starts the CLI or Python in a new process")
    config.addinivalue_line("markers", "ray: starts a local Ray cluster")


@pytest.fixture(scope="session")
def paper_arm():
    """The paper's arm (constants only: safe to share across tests)."""
    return hydroarm.load_arm("paper")


@pytest.fixture(scope="session")
def ur5_arm():
    return hydroarm.load_arm("ur5")


@pytest.fixture(scope="session")
def alpha5_arm():
    return hydroarm.load_arm("alpha5")
