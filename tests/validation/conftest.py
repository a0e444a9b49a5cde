"""The paper-units Rustrel runs, one per scene for the whole session.

These runs take ~10 s each on one core, so the set is opt-in: ``python -m pytest -q -m validation
tests/validation`` (CI runs it as a second step). Without ``-m validation`` they are skipped.
"""
from __future__ import annotations

from pathlib import Path

import pytest

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
SCENES = {
    "calibrated": "rustrel-2015-calibrated-paper-units.toml",
    "initial": "rustrel-2015-initial-paper-units.toml",
    "impermeable": "rustrel-2015-impermeable-paper-units.toml",
    "calibrated-si": "rustrel-2015-calibrated.toml",
}


def pytest_configure(config):
    config.addinivalue_line("markers", "validation: the paper's findings on full Rustrel runs (opt-in: -m validation)")


def pytest_collection_modifyitems(config, items):
    if "validation" in (config.getoption("markexpr") or ""):
        return
    skip = pytest.mark.skip(reason="validation runs are opt-in: python -m pytest -m validation tests/validation")
    for item in items:
        if "validation" in item.keywords:
            item.add_marker(skip)


class _Runs:
    """Runs each scene the first time it is asked for, then keeps the Result."""

    def __init__(self):
        self._results = {}

    def __getitem__(self, name):
        if name not in self._results:
            from fault_screen import Scene, simulate

            self._results[name] = simulate(Scene.from_toml(CONFIGS / SCENES[name]))
        return self._results[name]


@pytest.fixture(scope="session")
def rustrel_runs():
    return _Runs()
