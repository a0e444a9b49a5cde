"""The validation page's table (docs/validation.md) against the runs it quotes, to the digits shown:
peak overpressure, slip at the injection point at the end, slip onset, first yellow, unknowns and
the fluid budget. The impermeable SI row is checked in the quick suite (tests/docs/test_docs.py)."""
from __future__ import annotations

import re

import pytest

from test_docs import _validation_rows, check_validation_row

ROWS = {"calibrated": "calibrated-paper-units", "initial": "initial-paper-units",
        "impermeable": "impermeable-paper-units", "calibrated-si": "calibrated"}


@pytest.mark.validation
@pytest.mark.parametrize("run", sorted(ROWS))
def test_validation_table_row_is_the_run(run, rustrel_runs):
    check_validation_row(_validation_rows()[ROWS[run]], rustrel_runs[run])


def _kind_rows() -> list[list[str]]:
    from test_docs import DOCS

    text = (DOCS / "validation.md").read_text()
    table = text.split("| scene | kind |", 1)[1].split("\n\n", 1)[0].splitlines()[2:]
    return [[c.strip() for c in re.split(r"(?<!\\)\|", row.strip("|"))] for row in table]


KIND_SCENES = {"calibrated": "calibrated", "initial": "initial", "impermeable": "impermeable"}


@pytest.mark.validation
@pytest.mark.parametrize("scene_name", sorted(KIND_SCENES))
def test_stress_kind_table_rows_are_the_runs(scene_name, rustrel_runs):
    """The stress-reading table: the shipped fault-effective row is the shared run, the
    Biot-effective row a run of the same scene with its stresses read that way (peak overpressure,
    largest slip at the injection point, slip onset there, to the digits shown), and the total
    reading is refused with the ratio the table quotes."""
    import dataclasses

    import numpy as np

    from fault_screen import Scene, SceneError, simulate
    from fault_screen.stepper import Simulation

    from .conftest import CONFIGS, SCENES

    rows = {(r[0], r[1].split()[0]): r[2:] for r in _kind_rows()}
    base = Scene.from_toml(CONFIGS / SCENES[KIND_SCENES[scene_name]])
    given, _ = base.initial.stress_and_kind

    def with_kind(kind):
        return base.replace(initial=dataclasses.replace(base.initial, effective_stress=None, stress=given,
                                                        stress_kind=kind))

    for kind, result in (("fault_effective", rustrel_runs[KIND_SCENES[scene_name]]),
                         ("biot_effective", simulate(with_kind("biot_effective")))):
        peak, slip, onset = rows[(scene_name, kind)]
        at = int(np.argmin(np.abs(result.fault_x)))
        sliding = np.flatnonzero(result.fault["contact_state"][:, at] == 1)
        assert float(peak) == pytest.approx(result.injection["overpressure"].max() / 1e6, abs=0.0005)
        assert float(slip) == pytest.approx(np.abs(result.injection["slip"]).max() * 1e3, abs=0.0005)
        assert float(onset) == result.time[sliding[0]]
    refusal = rows[("any", "total")][0]
    ratio = re.search(r"= ([\d.]+) > mu0", refusal)[1]
    mu0 = re.search(rf"([\d.]+) {scene_name}\b", refusal)[1]
    with pytest.raises(SceneError, match=rf"\|tau0\| / sigma'_n0 = {re.escape(ratio)} > mu0 = {re.escape(mu0)} "):
        Simulation(with_kind("total"))
