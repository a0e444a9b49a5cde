import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"
VERIFICATION = CONFIGS / "verification"
sys.path.insert(0, str(Path(__file__).resolve().parent))  # tests/analytical.py
# the test files sit in folders mirroring the package (tests/physics, tests/solver, ...) with unique
# basenames and no __init__.py; a few import another's cases (test_forecast_fork from test_stepper,
# validation/test_docs_tables from test_docs), so every folder is importable whatever pytest collects
sys.path.extend(str(folder) for folder in sorted(Path(__file__).resolve().parent.iterdir())
                if folder.is_dir() and next(folder.glob("test_*.py"), None) is not None)


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
