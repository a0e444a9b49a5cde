"""Fixtures shared by the monitor tests."""
from __future__ import annotations

import pytest

import monitor_env


@pytest.fixture(scope="session")
def dist(tmp_path_factory):
    """A folder with the project's entry points (``*.dist-info``), on this interpreter's path:
    the source and alert plugins are found by entry points, as when installed."""
    folder = tmp_path_factory.mktemp("dist")
    monitor_env.activate(folder)
    return folder


# pytest imports this file under the module name ``conftest``, replacing tests/conftest.py under
# that name (neither folder is a package); the test modules collected after it import the
# shared paths of tests/conftest.py by that name, so they are here too
from monitor_env import ROOT  # noqa: E402

CONFIGS = ROOT / "configs"
VERIFICATION = CONFIGS / "verification"
