import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))              # cases.py
sys.path.insert(0, str(HERE.parent))       # tests/analytical.py

from cases import run_case  # noqa: E402


@pytest.fixture(scope="session")
def hard_run():
    """run_case, shared by the whole session: every case runs once."""
    return run_case
