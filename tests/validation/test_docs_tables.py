"""The validation page's table (docs/validation.md) against the runs it quotes, to the digits shown:
peak overpressure, slip at the injection point at the end, slip onset, first yellow, unknowns and
the fluid budget. The impermeable SI row is checked in the quick suite (tests/test_docs.py)."""
from __future__ import annotations

import pytest

from test_docs import _validation_rows, check_validation_row

ROWS = {"calibrated": "calibrated-paper-units", "initial": "initial-paper-units",
        "impermeable": "impermeable-paper-units", "calibrated-si": "calibrated"}


@pytest.mark.validation
@pytest.mark.parametrize("run", sorted(ROWS))
def test_validation_table_row_is_the_run(run, rustrel_runs):
    check_validation_row(_validation_rows()[ROWS[run]], rustrel_runs[run])
