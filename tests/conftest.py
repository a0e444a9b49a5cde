import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"
VERIFICATION = CONFIGS / "verification"
sys.path.insert(0, str(Path(__file__).resolve().parent))  # tests/analytical.py


@pytest.fixture(scope="session")
def bundled_run():
    """``bundled_run(name)``: the whole run of a bundled scene (``configs/<name>.toml``) through
    the public API (screened), made once per test session and shared by every test that reads it."""
    import fault_screen
    from fault_screen import Scene

    cache = {}

    def run(name):
        if name not in cache:
            cache[name] = fault_screen.simulate(Scene.from_toml(CONFIGS / f"{name}.toml"))
        return cache[name]

    return run
