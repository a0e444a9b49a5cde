"""Fixtures shared by the monitor tests."""
from __future__ import annotations

import dataclasses

import pytest

import monitor_env


@pytest.fixture(scope="session")
def dist(tmp_path_factory):
    """A folder with the project's entry points (``*.dist-info``), on this interpreter's path:
    the source and alert plugins are found by entry points, as when installed."""
    folder = tmp_path_factory.mktemp("dist")
    monitor_env.activate(folder)
    return folder


@pytest.fixture(scope="session")
def scene_file(tmp_path_factory):
    """The impermeable Rustrel scene with steps of 10 s (the look-ahead tests' live model; its
    first yellow at 390 s of the stand-in log)."""
    from fault_screen import Scene

    s = Scene.from_toml(CONFIGS / "rustrel-2015-impermeable.toml")
    s = s.replace(time=dataclasses.replace(s.time, dt=10.0))
    path = tmp_path_factory.mktemp("scene") / "impermeable-10s.toml"
    path.write_text(s.to_toml())
    return path


@pytest.fixture(scope="session")
def log():
    """The bundled Rustrel stand-in injection log."""
    from fault_screen.io.injection_log import read_injection_log

    return read_injection_log(CONFIGS / "logs" / "rustrel-2015-standin.csv")


# pytest imports this file under the module name ``conftest``, replacing tests/conftest.py under
# that name (neither folder is a package); the test modules collected after it import the
# shared paths of tests/conftest.py by that name, so they are here too
from monitor_env import ROOT  # noqa: E402

CONFIGS = ROOT / "configs"
VERIFICATION = CONFIGS / "verification"
