"""One row's fault metrics (the per-step path) equal, float for float, those of a block holding
that row alone (the path that screens a whole result): the per-step path computes them in fewer
numpy calls and must not change a single bit, NaN, open points and tension included."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from fault_screen.screening.metrics import FAULT_METRICS, fault_metrics

N_POINTS = 7
values = st.floats(allow_infinity=False, width=64, min_value=-1e7, max_value=1e7) | st.just(0.0) | st.just(np.nan)
fields = st.fixed_dictionaries({
    "slip_rate": arrays(float, N_POINTS, elements=values),
    "contact_state": arrays(np.int64, N_POINTS, elements=st.integers(0, 2)),
    "shear_traction": arrays(float, N_POINTS, elements=values),
    "effective_normal_stress": arrays(float, N_POINTS, elements=values),
})


def same(a, b):
    return (math.isnan(a) and math.isnan(b)) or a == b


@settings(max_examples=300, deadline=None)
@given(row=fields, mu0=st.floats(0.05, 1.5))
def test_a_row_gives_the_floats_of_a_block_of_that_row(row, mu0):
    x = np.linspace(-3.0, 3.0, N_POINTS)
    w = np.linspace(0.5, 1.1, N_POINTS)
    one = fault_metrics(row, x, w, mu0)
    block = fault_metrics({k: v[None, :] for k, v in row.items()}, x, w, mu0)
    assert set(one) == set(FAULT_METRICS)
    for k in FAULT_METRICS:
        assert isinstance(one[k], float)
        assert same(one[k], float(block[k][0])), (k, one[k], block[k])


def test_a_row_by_hand():
    # utilisation 0.5 / (0.6 * 2) at the point in compression, 1 where open or in tension; the
    # peak rate at x = 1 (the first of two equal peaks)
    row = {"slip_rate": np.array([0.0, 2e-6, -2e-6]), "contact_state": np.array([0, 1, 2]),
           "shear_traction": np.array([0.5e6, 0.1e6, 0.0]),
           "effective_normal_stress": np.array([2e6, -1e6, 1e6])}
    m = fault_metrics(row, np.array([0.0, 1.0, 2.0]), np.array([1.0, 0.25, 1.0]), 0.6)
    assert m["peak_slip_rate"] == 2e-6 and m["x_peak_slip_rate"] == 1.0
    assert m["slipping_length"] == 0.25
    assert m["max_utilisation"] == 1.0
    assert m["min_coulomb_margin"] == -0.1e6     # 0 strength in tension minus 0.1 MPa
    row["contact_state"] = np.array([0, 0, 0])
    row["effective_normal_stress"] = np.array([2e6, 1e6, 1e6])
    row["slip_rate"] = np.zeros(3)
    m = fault_metrics(row, np.array([0.0, 1.0, 2.0]), np.array([1.0, 0.25, 1.0]), 0.6)
    assert m["max_utilisation"] == 0.5e6 / 1.2e6 and math.isnan(m["x_peak_slip_rate"])
    assert m["min_coulomb_margin"] == pytest.approx(0.5e6, rel=1e-15)   # 0.6 MPa - 0.1 MPa
